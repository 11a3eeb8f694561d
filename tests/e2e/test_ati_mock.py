"""End to end: tmscal's ATINetFT driver reads the ATI Net F/T mock over real UDP datagrams on
loopback; lost, reordered and faulty records, and a silent sensor, are typed errors."""

from __future__ import annotations

import math
import socket
from pathlib import Path

import numpy as np
import pytest

from tests.rigs import NOISE_FREE_MOCK, free_port, unique_host, wait_until, write_config
from tmscal.acquisition.devices import make_ft
from tmscal.config import load_config
from tmscal.drivers.ati import codec
from tmscal.drivers.ati.sensor import ATINetFT
from tmscal.errors import ConnectionLost, DeviceError, DeviceTimeout
from tmscal.geometry import make_pose, rot_x
from tmscal.mocks.ati import ATIFaults, ATINetFTMock
from tmscal.mocks.clock import FAST, REAL_TIME
from tmscal.mocks.launch import start_mock_rig
from tmscal.mocks.wrench import gravity_wrench_source
from tmscal.net import NotLoopbackError
from tmscal.sim.rig import Noise, SimRig, tms_rig_truth

pytestmark = pytest.mark.e2e

#: a wrench with distinct values per channel (N, N·m)
W = np.array([1.5, -2.25, 9.0, 0.125, -0.5, 0.0625])


def _sensor(mock: ATINetFTMock, cpf: float = 1e6, cpt: float = 1e6, **kw: object) -> ATINetFT:
    return ATINetFT("127.0.0.1", cpf, cpt, port=mock.port, **kw)  # type: ignore[arg-type]


@pytest.mark.parametrize("clock", [FAST, REAL_TIME], ids=["fast", "real"])
def test_reads_the_source_in_units(clock: object) -> None:
    """Counts per unit differ between force and torque and between mock and a wrong driver
    setting: only the matching setting gives the source back."""
    with ATINetFTMock(lambda: W, clock=clock, counts_per_force=4e5,  # type: ignore[arg-type]
                      counts_per_torque=2.5e6, rate_hz=2000.0) as mock:
        with _sensor(mock, 4e5, 2.5e6) as ft:
            w = ft.read(50)
            assert ft.lost == 0 and ft.reordered == 0
            wrong = _sensor(mock, 1e6, 1e6)
        with wrong:
            w_wrong = wrong.read(1)
    assert w.shape == (50, 6)
    np.testing.assert_allclose(w, np.tile(W, (50, 1)), atol=0.5 / 4e5)   # half a count
    assert abs(w_wrong[0, 0] - W[0] * 0.4) < 1e-5 and abs(w_wrong[0, 3] - W[3] * 2.5) < 1e-5


def test_noise_is_the_configured_sigma() -> None:
    """σ 0.33 N / 0.066 N·m (the paper's ±1 N / ±0.2 N·m as 3σ); 2000 samples, seed 3: the
    sample SD is within 10 % of σ (its relative SE is 1/√(2·2000) ≈ 1.6 %)."""
    with ATINetFTMock(lambda: W, clock=FAST, noise_n=0.33, noise_nm=0.066, seed=3) as mock:
        with _sensor(mock) as ft:
            w = ft.read(2000)
    sd = w.std(axis=0, ddof=1)
    np.testing.assert_allclose(sd, [0.33] * 3 + [0.066] * 3, rtol=0.10)
    np.testing.assert_allclose(w.mean(axis=0), W, atol=4 * 0.33 / math.sqrt(2000))


def test_rig_gravity_wrench_by_hand() -> None:
    """The sim rig without an arm: a 1.5 kg load 60 mm along the flange z axis, the flange
    rotated 90° about the base x axis (z up). By hand: f = Rᵀ(0, 0, −m g) = (0, −m g, 0),
    τ = c × f = (c·m g, 0, 0), m g = 1.5 · 9.80665 N."""
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=make_pose(rot_x(math.pi / 2),
                                                                      [500.0, 0.0, 400.0]))
    mg = 1.5 * 9.80665
    with ATINetFTMock(gravity_wrench_source(rig), clock=FAST) as mock:
        with _sensor(mock) as ft:
            w = ft.read(3).mean(axis=0)
    np.testing.assert_allclose(w, [0.0, -mg, 0.0, 0.06 * mg, 0.0, 0.0], atol=1e-5)


def test_software_bias_zeroes_the_reading() -> None:
    with ATINetFTMock(lambda: W, clock=FAST) as mock:
        with _sensor(mock) as ft:
            ft.bias()
            w = ft.read(5)
        assert (codec.SET_SOFTWARE_BIAS, 0) in mock.requests
    np.testing.assert_allclose(w, 0.0, atol=1e-6)


def test_close_stops_the_stream() -> None:
    with ATINetFTMock(lambda: W, clock=FAST) as mock:
        with _sensor(mock) as ft:
            ft.read(2)
            n = len(mock.requests)
        wait_until(lambda: len(mock.requests) > n, 5.0, "the STOP sent by close()")
        assert mock.requests[-1] == (codec.STOP, 0)


def test_lost_records_within_tolerance_are_replaced_and_counted() -> None:
    """Every 25th record dropped, 100 asked: 4 lost (≤ 5 % of 100), 100 returned."""
    with ATINetFTMock(lambda: W, clock=FAST, faults=ATIFaults(drop_every=25)) as mock:
        with _sensor(mock, timeout_s=0.3) as ft:
            w = ft.read(100)
            lost, reordered = ft.lost, ft.reordered
    assert w.shape == (100, 6)
    assert lost == 4 and reordered == 0


def test_too_many_lost_records_is_a_device_error_naming_the_counts() -> None:
    with ATINetFTMock(lambda: W, clock=FAST, faults=ATIFaults(drop_every=3)) as mock:
        with _sensor(mock, timeout_s=0.3) as ft, pytest.raises(DeviceError) as e:
            ft.read(100)
    assert "6 records lost and 0 reordered" in str(e.value)
    assert "max_lost_share" in str(e.value)


def test_reordered_records_are_counted() -> None:
    """Every 10th record comes after the next one: 10 reordered in 100 (the tolerance raised
    to 20 %); the late records are dropped and replaced, the order kept."""
    with ATINetFTMock(lambda: W, clock=FAST, faults=ATIFaults(reorder_every=10)) as mock:
        with _sensor(mock, timeout_s=0.3, max_lost_share=0.2) as ft:
            w = ft.read(100)
            assert ft.reordered >= 9 and ft.lost == 0
        with _sensor(mock, timeout_s=0.3) as ft, pytest.raises(DeviceError, match="reordered"):
            ft.read(100)
    assert w.shape == (100, 6)


def test_bad_status_is_a_device_error_with_the_bits() -> None:
    with ATINetFTMock(lambda: W, clock=FAST,
                      faults=ATIFaults(bad_status_from=3, bad_status=0x80000004)) as mock:
        with _sensor(mock) as ft, pytest.raises(DeviceError) as e:
            ft.read(10)
    assert e.value.code == 0x80000004
    assert "bit 31 (error summary)" in str(e.value) and "bit 2" in str(e.value)
    assert "record 3" in str(e.value)


def test_silent_sensor_is_a_timeout() -> None:
    with ATINetFTMock(lambda: W, clock=FAST, faults=ATIFaults(mute=True)) as mock:
        with _sensor(mock, timeout_s=0.2) as ft, pytest.raises(DeviceTimeout,
                                                                  match="0 of 4 received"):
            ft.read(4)


def test_nobody_listening_is_connection_lost() -> None:
    host = unique_host()
    ft = ATINetFT(host, 1e6, 1e6, port=free_port(host, udp=True), timeout_s=0.5)
    with pytest.raises((ConnectionLost, DeviceTimeout)):
        with ft:
            ft.read(1)


def test_junk_datagrams_are_skipped(caplog: pytest.LogCaptureFixture) -> None:
    """A datagram of the wrong length from the sensor's port, in the middle of a stream, is
    not a record: skipped, and the stream read on."""
    sent: list[bool] = []
    box: dict[str, object] = {}

    def source() -> np.ndarray:   # called by the mock just before it sends each record
        mock, ft = box["mock"], box["ft"]
        if len(sent) == 1:
            mock._sock.sendto(b"\x00" * 35, ft._sock.getsockname())  # type: ignore[attr-defined]
        sent.append(True)
        return W

    with ATINetFTMock(source, clock=FAST) as mock:
        with _sensor(mock) as ft:
            box.update(mock=mock, ft=ft)
            w = ft.read(3)
            assert ft.lost == 0 and ft.reordered == 0
    assert len(sent) == 3
    assert "length 35 bytes, expected 36; datagram skipped" in caplog.text
    np.testing.assert_allclose(w, np.tile(W, (3, 1)), atol=1e-6)


@pytest.mark.parametrize("host", ["0.0.0.0", "192.0.2.1"])
def test_mock_refuses_a_non_loopback_host(host: str) -> None:
    with pytest.raises(NotLoopbackError, match="loopback"):
        ATINetFTMock(lambda: W, host=host)


def test_mock_binds_loopback_udp() -> None:
    with ATINetFTMock(lambda: W, clock=FAST) as mock:
        host, port = mock.getsockname()
    assert host == "127.0.0.1" and port > 0


def _ft_config(tmp_path: Path, **mock: object) -> Path:
    return write_config(tmp_path, "mock-denso-polaris.yaml",
                        ft={"driver": "ati", "host": "127.0.0.1", "port": 0,
                            "counts_per_force": 1e6, "counts_per_torque": 1e6, "samples": 5},
                        mock={"noise": NOISE_FREE_MOCK, **mock})


def test_mock_rig_serves_the_gravity_wrench_of_the_rig(tmp_path: Path) -> None:
    """``tmscal mock``'s rig with an ``ft`` section: the Net F/T mock serves the load at the
    rig's flange, read through make_ft (by hand: f = Rᵀ(0, 0, −m g), τ = c × f)."""
    cfg = load_config(_ft_config(tmp_path))
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        port = int(mr.endpoints["ft"].rsplit(":", 1)[1])
        with make_ft(cfg, port=port) as ft:
            w = ft.read(cfg.ft.samples).mean(axis=0)   # type: ignore[union-attr]
        R = mr.rig.true_flange()[:3, :3]
    f = R.T @ [0.0, 0.0, -1.5 * 9.80665]
    tau = np.cross([0.0, 0.0, 0.060], f)
    np.testing.assert_allclose(w, np.concatenate([f, tau]), atol=2e-6)


def test_mock_rig_with_an_arm_serves_the_true_arms_wrench(tmp_path: Path) -> None:
    """With ``mock.kinematics`` the wrench is the TRUE arm's at the rig's joints, which
    differs from what the controller's nominal arm predicts by the hidden errors."""
    from tmscal.calib.selfcal.model import wrench

    cfg = load_config(_ft_config(tmp_path, kinematics={"arm": "ur5e", "errors": "paper"}))
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        port = int(mr.endpoints["ft"].rsplit(":", 1)[1])
        with make_ft(cfg, port=port) as ft:
            w = ft.read(3).mean(axis=0)
        q = mr.rig.joints()
        true, nominal = mr.rig.arm_true, mr.rig.arm_nominal
    assert q is not None and true is not None and nominal is not None
    np.testing.assert_allclose(w, wrench(true, q[None])[0], atol=2e-6)
    assert np.abs(w - wrench(nominal, q[None])[0]).max() > 1e-3


def test_mock_rig_refuses_a_public_ft_host(tmp_path: Path) -> None:
    p = write_config(tmp_path, "mock-denso-polaris.yaml",
                     ft={"driver": "ati", "host": "0.0.0.0", "counts_per_force": 1e6,
                         "counts_per_torque": 1e6})
    with pytest.raises(NotLoopbackError, match="key 'ft.host'"):
        start_mock_rig(load_config(p), tracker_transport="pty")


def test_mock_ft_faults_reach_the_mock(tmp_path: Path) -> None:
    cfg = load_config(_ft_config(tmp_path, ft={"faults": {"bad_status_from": 1}}))
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        port = int(mr.endpoints["ft"].rsplit(":", 1)[1])
        with make_ft(cfg, port=port) as ft, pytest.raises(DeviceError, match="error summary"):
            ft.read(2)


def test_mock_ignores_hostile_datagrams_and_serves_on() -> None:
    """Empty, short, long, bad-header, unknown-command and random datagrams are ignored (as
    the sensor ignores them); a request after them is served."""
    junk = [b"", b"\x12\x34\x00\x02\x00\x00\x00", bytes(9), bytes.fromhex("43210002 00000001"),
            bytes.fromhex("12340005 00000001"), np.random.default_rng(1).bytes(1000)]
    with ATINetFTMock(lambda: W, clock=FAST) as mock:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for j in junk:
                s.sendto(j, ("127.0.0.1", mock.port))
        with _sensor(mock) as ft:
            w = ft.read(2)
        assert all(cmd in codec.COMMANDS for cmd, _ in mock.requests)
    np.testing.assert_allclose(w, np.tile(W, (2, 1)), atol=1e-6)
