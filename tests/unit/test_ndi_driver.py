"""Our NDI driver against our Polaris mock (pty and TCP, fast clock), including every injected
fault, and the mock's state machine answered command by command."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from tmscal.drivers.base import driver_class
from tmscal.drivers.ndi import protocol as p
from tmscal.drivers.ndi.tracker import NDITracker
from tmscal.errors import ConfigError, DeviceError, DeviceTimeout, ProtocolError
from tmscal.geometry import make_pose, rotation_angle
from tmscal.mocks.clock import FAST
from tmscal.mocks.polaris import MeasurementVolume, PolarisFaults, PolarisMock
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

TOOLS_DIR = Path(__file__).resolve().parents[2] / "configs" / "tools"
ROMS = {"marker": str(TOOLS_DIR / "marker-8700340.rom"),
        "probe": str(TOOLS_DIR / "probe-8700340.rom")}
FAST_OPTS = {"timeout_s": 0.3, "reset": False, "baud": 115200}


def make_rig(noise: Noise | None = None) -> SimRig:
    return SimRig(tms_rig_truth(), noise=noise or Noise.none(),
                  rng=np.random.default_rng(1), start=TMS_RIG_P0)


@pytest.fixture
def rig() -> SimRig:
    return make_rig()


@pytest.fixture
def mock(rig: SimRig) -> Iterator[PolarisMock]:
    with PolarisMock(rig, ROMS, clock=FAST, seed=3) as m:
        yield m


def cmd(m: PolarisMock, name: str, params: str = "") -> p.Reply | bytes:
    """Send one command to the mock directly; text replies are parsed, BX returned raw."""
    raw = m.handle_line(p.encode_command(name, params)[:-1])
    assert raw is not None
    return raw if raw[:2] == b"\xc4\xa5" else p.parse_reply(raw)


def err(m: PolarisMock, name: str, params: str = "") -> int | None:
    r = cmd(m, name, params)
    assert isinstance(r, p.Reply)
    return r.code if r.kind == "error" else None


# --- driver against the mock --------------------------------------------------------------------

@pytest.mark.parametrize("transport", ["pty", "tcp"])
@pytest.mark.parametrize("reply", ["bx", "tx"])
def test_poses_equal_rig_truth(mock: PolarisMock, rig: SimRig, transport: str,
                               reply: str) -> None:
    ep = mock.start_pty() if transport == "pty" else mock.start_tcp()
    # probe listed first: handles are matched to bodies by ROM bytes, not by order
    tools = {"probe": ROMS["probe"], "marker": ROMS["marker"]}
    with NDITracker(ep, tools, reply=reply, **FAST_OPTS) as tr:
        frames = [tr.read() for _ in range(3)]
    assert [f.frame for f in frames] == sorted({f.frame for f in frames})
    tol = 2e-4 if reply == "bx" else 6e-3  # float32 vs TX's 0.01 mm / 1e-4 quaternion
    for f in frames:
        assert set(f.tools) == {"probe", "marker"}
        for name, st in f.tools.items():
            assert st.usable and st.port_status == 0x31
            assert st.error_mm == pytest.approx(0.1, abs=1e-4)
            truth = rig.true_body(name)
            np.testing.assert_allclose(st.pose[:3, 3], truth[:3, 3], atol=tol)
            assert rotation_angle(st.pose[:3, :3].T @ truth[:3, :3]) < 5e-4


def test_command_sequence_and_clean_close(mock: PolarisMock) -> None:
    ep = mock.start_pty()
    tr = NDITracker(ep, ROMS, **FAST_OPTS)
    with tr:
        tr.read()
        ident = tr.identity()
    seq = mock.commands
    assert seq[:6] == ["INIT:", "VER:4", "GETINFO:Features.Firmware.Version", "COMM:50000",
                       "PHSR:01", "PHSR:00"]
    assert seq[6] == "PHRQ:*********1****"
    pvwr = [c for c in seq if c.startswith("PVWR:")]
    assert len(pvwr) == 2 * 10  # 600-byte ROMs → 10 chunks of 64 bytes each
    assert pvwr[0].startswith("PVWR:010000") and pvwr[9].startswith("PVWR:010240")
    assert seq.index("PINIT:01") < seq.index("PENA:01D") < seq.index("TSTART:")
    assert seq[-2:] == ["BX:0801", "TSTOP:"]
    assert ident["model"] == "Polaris Spectra" and ident["firmware"] == "Polaris Spectra Rev 007"
    assert ident["serial"] == "P6-00001" and ident["handles"] == {"marker": 1, "probe": 2}
    assert not tr.is_open
    tr.close()  # twice is fine


def test_high_baud_and_registry(mock: PolarisMock) -> None:
    cls = driver_class("ndi")
    assert cls is NDITracker
    with cls(mock.start_pty(), ROMS, timeout_s=0.3, reset=False, baud=921600) as tr:
        assert tr.read().tools["marker"].usable
    assert "COMM:60000" in mock.commands  # a serial line: the rate is raised


def test_break_reset_falls_back_to_init(mock: PolarisMock) -> None:
    # a pty cannot carry a break: no RESET answer, the driver carries on with INIT
    with NDITracker(mock.start_pty(), ROMS, timeout_s=0.3, reset=True,
                    reset_timeout_s=0.05) as tr:
        assert tr.read().tools["probe"].usable


def test_stale_handles_are_freed(mock: PolarisMock) -> None:
    ep = mock.start_pty()
    for _ in range(2):
        with NDITracker(ep, ROMS, **FAST_OPTS) as tr:
            tr.read()
    assert sorted(mock.handles.values()) == ["marker", "probe"]
    assert "PHF:01" in mock.commands and "PHF:02" in mock.commands


def test_tools_already_loaded_on_the_device(mock: PolarisMock, rig: SimRig) -> None:
    ep = mock.start_tcp()
    with NDITracker(ep, ROMS, **FAST_OPTS):
        pass
    n = len(mock.commands)
    with NDITracker(ep, {"marker": None, "probe": None}, timeout_s=0.3) as tr:
        f = tr.read()
    assert not any(c.startswith(("PVWR", "PHRQ", "PHF")) for c in mock.commands[n:])
    np.testing.assert_allclose(f.pose("probe")[:3, 3], rig.true_body("probe")[:3, 3],
                               atol=1e-3)
    with pytest.raises(DeviceError, match="only 2 occupied handles"):
        with NDITracker(ep, {"a": None, "b": None, "c": None}, timeout_s=0.3):
            pass


def test_distinct_frames_skip_repeats_on_the_real_driver(mock: PolarisMock) -> None:
    with NDITracker(mock.start_pty(), ROMS, **FAST_OPTS) as tr:
        frames = list(tr.distinct_frames(5))
    nums = [f.frame for f in frames]
    assert len(set(nums)) == 5 and nums == sorted(nums)


def test_missing_rom_file_is_a_config_error(mock: PolarisMock, tmp_path: Path) -> None:
    tr = NDITracker(mock.start_pty(), {"marker": str(tmp_path / "nope.rom")}, **FAST_OPTS)
    with pytest.raises(ConfigError, match="marker"):
        tr.open()
    assert not tr.is_open


def _rom(size: int, fill: bytes = b"\x5a") -> bytes:
    """A binary tool definition of ``size`` bytes: ``NDI``, a zero byte, then ``fill``."""
    return (b"NDI\0" + fill * size)[:size]


BAD_ROMS = {
    "too big": (_rom(1025), "1025 bytes"),
    "huge": (_rom(4096) * 256, "1048576 bytes"),
    "empty": (b"", "empty"),
    "yaml": (b"tracker:\n  port: /dev/ttyUSB0\n", "does not start with 'NDI'"),
    "text with the magic": (b"NDI tool definition, honest\n", "text file"),
    "no magic": (b"\x00\x01\x02" * 100, "does not start with 'NDI'"),
}


@pytest.mark.parametrize("kind", list(BAD_ROMS))
def test_bad_rom_file_refused_before_anything_is_sent(mock: PolarisMock, tmp_path: Path,
                                                      kind: str) -> None:
    """A file named as a tool ROM that is no NDI tool definition (over 1024 bytes, empty,
    text, without the NDI header) is refused with a ConfigError naming the tool and the file
    before a single byte goes to the tracker."""
    data, why = BAD_ROMS[kind]
    bad = tmp_path / "probe.rom"
    bad.write_bytes(data)
    tr = NDITracker(mock.start_pty(), {"marker": ROMS["marker"], "probe": str(bad)},
                    **FAST_OPTS)
    with pytest.raises(ConfigError) as ei:
        tr.open()
    msg = str(ei.value)
    assert "'probe'" in msg and str(bad) in msg and why in msg
    assert not tr.is_open
    assert mock.commands == []          # nothing was sent, not even INIT


def test_rom_that_is_not_a_regular_file_is_refused(mock: PolarisMock, tmp_path: Path) -> None:
    import os

    fifo = tmp_path / "fifo.rom"
    os.mkfifo(fifo)         # would block a plain open() waiting for a writer
    for path in (tmp_path, fifo):
        tr = NDITracker(mock.start_pty(), {"marker": str(path)}, **FAST_OPTS)
        with pytest.raises(ConfigError, match="not a regular file") as ei:
            tr.open()
        assert "'marker'" in str(ei.value)
    assert mock.commands == []


def test_rom_of_exactly_1024_bytes_is_uploaded_whole(mock: PolarisMock, tmp_path: Path) -> None:
    """The largest tool definition PVWR can write: 16 chunks of 64 bytes, all sent."""
    rom = tmp_path / "big.rom"
    rom.write_bytes(_rom(1024))
    with NDITracker(mock.start_pty(), {"marker": str(rom)}, **FAST_OPTS) as tr:
        h = tr.handles["marker"]
    pvwr = [c for c in mock.commands if c.startswith("PVWR")]
    assert [c[5:11] for c in pvwr] == [f"{h:02X}{a:04X}" for a in range(0, 1024, 64)]
    sent = bytes.fromhex("".join(c[11:11 + 128] for c in pvwr))
    assert sent == _rom(1024)


def test_rom_upload_to_a_remote_host_is_warned(caplog: pytest.LogCaptureFixture) -> None:
    """read_roms names a non-loopback socket:// host that would receive the tool
    definitions; a device path or a loopback address gets no warning."""
    import logging

    from tmscal.drivers.ndi.rom import read_roms
    from tmscal.drivers.ndi.wire import remote_host

    with caplog.at_level(logging.WARNING):
        roms = read_roms(ROMS, "socket://192.0.2.7:8765")
    assert set(roms) == {"marker", "probe"}
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1
    assert "uploading ROM files to a remote host" in warned[0] and "192.0.2.7" in warned[0]
    assert "marker" in warned[0] and "probe" in warned[0]
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        for port in ("/dev/ttyUSB0", "socket://127.0.0.1:8765", "socket://[::1]:8765",
                     "socket://localhost:8765", "socket://127.3.4.5:1"):
            read_roms(ROMS, port)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert remote_host("socket://tracker.lab:8765") == "tracker.lab"
    assert remote_host("socket://[2001:db8::1]:8765") == "2001:db8::1"
    assert remote_host("COM3") is None


def test_rom_upload_over_loopback_socket_is_not_warned(mock: PolarisMock,
                                                       caplog: pytest.LogCaptureFixture
                                                       ) -> None:
    import logging

    with caplog.at_level(logging.WARNING), NDITracker(mock.start_tcp(), ROMS, **FAST_OPTS):
        pass
    assert not [r for r in caplog.records if "remote host" in r.getMessage()]


def test_device_error_carries_code_and_meaning(mock: PolarisMock) -> None:
    with NDITracker(mock.start_pty(), ROMS, **FAST_OPTS) as tr:
        with pytest.raises(DeviceError) as ei:
            tr._command("PHSR", "00")  # not allowed while tracking
        assert ei.value.code == 0x0C
        assert ei.value.text == "command is invalid while in the current mode"
        assert tr.read().tools["marker"].usable  # the session is still fine


# --- faults -------------------------------------------------------------------------------------

def fault_mock(rig: SimRig, **kw) -> PolarisMock:
    return PolarisMock(rig, ROMS, clock=FAST, seed=7, faults=PolarisFaults(**kw))


@pytest.mark.parametrize("reply", ["bx", "tx"])
def test_crc_errors_are_retried(rig: SimRig, reply: str) -> None:
    with fault_mock(rig, crc_error_prob=0.3) as m:
        with NDITracker(m.start_pty(), ROMS, reply=reply, retries=6, **FAST_OPTS) as tr:
            frames = [tr.read() for _ in range(60)]
        sent = sum(c.startswith(reply.upper() + ":") for c in m.commands)
    assert sent > 60  # some requests were re-sent
    for f in frames:
        np.testing.assert_allclose(f.pose("marker")[:3, 3], rig.true_body("marker")[:3, 3],
                                   atol=6e-3)


def test_persistent_crc_errors_raise_protocol_error(rig: SimRig) -> None:
    with fault_mock(rig, crc_error_prob=1.0) as m:
        with NDITracker(m.start_pty(), ROMS, retries=2, **FAST_OPTS) as tr:
            with pytest.raises(ProtocolError, match="BX.*CRC.*3 attempts"):
                tr.read()
        assert sum(c.startswith("BX:") for c in m.commands) == 3
        assert m.commands[-1] == "TSTOP:"


def test_dropped_replies_time_out_and_are_retried(rig: SimRig) -> None:
    with fault_mock(rig, drop_reply_prob=0.3) as m:
        with NDITracker(m.start_tcp(), ROMS, reply="bx", retries=8, timeout_s=0.3,
                        reset=False) as tr:
            frames = [tr.read() for _ in range(20)]
        sent = sum(c.startswith("BX:") for c in m.commands)
    assert sent > 20
    assert all(f.tools["probe"].usable for f in frames)


def test_persistent_drops_raise_device_timeout_naming_the_command(rig: SimRig) -> None:
    # the setup's replies come (only tracking replies are dropped), however slowly a loaded
    # machine runs the mock: a timeout of a second, not 0.05 s, waits for them
    with fault_mock(rig, drop_reply_prob=1.0) as m:
        with NDITracker(m.start_pty(), ROMS, retries=1, timeout_s=1.0, reset=False) as tr:
            with pytest.raises(DeviceTimeout, match="no reply to BX"):
                tr.read()
    with fault_mock(rig, drop_reply_prob=1.0, tracking_only=False) as m:
        tr = NDITracker(m.start_pty(), ROMS, retries=1, timeout_s=0.05, reset=False,
                        baud=9600)
        with pytest.raises(DeviceTimeout, match="no reply to INIT"):
            tr.open()
        assert not tr.is_open and tr._ser is None


def test_setup_survives_faults_on_every_reply(rig: SimRig) -> None:
    with fault_mock(rig, crc_error_prob=0.2, tracking_only=False) as m:
        with NDITracker(m.start_pty(), ROMS, retries=8, **FAST_OPTS) as tr:
            assert tr.read().tools["marker"].usable


def test_missing_tools_appear_as_missing(rig: SimRig) -> None:
    with fault_mock(rig, missing_fraction=0.5) as m:
        with NDITracker(m.start_pty(), ROMS, **FAST_OPTS) as tr:
            frames = [tr.read() for _ in range(200)]
    states = [f.tools[t] for f in frames for t in ("marker", "probe")]
    missing = [s for s in states if s.missing]
    assert 0.35 < len(missing) / len(states) < 0.65
    assert all(s.pose is None and not s.usable and s.port_status == 0x31 for s in missing)
    assert all(s.pose is not None for s in states if not s.missing)


def test_ir_interference_is_flagged(rig: SimRig) -> None:
    with fault_mock(rig, ir_interference_fraction=1.0) as m:
        with NDITracker(m.start_pty(), ROMS, reply="tx", **FAST_OPTS) as tr:
            f = tr.read()
    assert f.system_status & p.SystemStatus.TOO_MUCH_EXTERNAL_INFRARED
    assert all(s.port_status & p.PortStatus.IR_INTERFERENCE for s in f.tools.values())
    assert all(s.pose is not None for s in f.tools.values())


def test_status_bits_are_logged_once_per_change(rig: SimRig, caplog) -> None:
    with fault_mock(rig, ir_interference_fraction=1.0) as m:
        with NDITracker(m.start_pty(), ROMS, **FAST_OPTS) as tr:
            with caplog.at_level("WARNING", logger="tmscal.drivers.ndi.tracker"):
                for _ in range(5):
                    tr.read()
    msgs = [r.getMessage() for r in caplog.records]
    assert msgs.count("ndi: system status TOO_MUCH_EXTERNAL_INFRARED") == 1
    assert msgs.count("ndi: marker status IR_INTERFERENCE") == 1
    assert msgs.count("ndi: probe status IR_INTERFERENCE") == 1


def test_out_of_volume(rig: SimRig) -> None:
    # move the flange 1 m up: tools at z ≈ -500 mm, in front of the near plane (-950)
    rig.move_flange(make_pose(np.diag([1.0, -1.0, -1.0]), [500.0, -1000.0, 400.0]))
    assert rig.true_body("probe")[2, 3] > -950
    with PolarisMock(rig, ROMS, clock=FAST) as m:
        ep = m.start_pty()
        with NDITracker(ep, ROMS, **FAST_OPTS) as tr:  # option 0801: transform still sent
            s = tr.read().tools["probe"]
        assert s.out_of_volume and not s.missing and s.pose is not None and not s.usable
        with NDITracker(ep, ROMS, reply_options=0x0001, **FAST_OPTS) as tr:
            s = tr.read().tools["probe"]
        assert s.out_of_volume and s.missing and s.pose is None


def test_partially_out_of_volume(rig: SimRig) -> None:
    # a volume whose x limit cuts through the tools (spheres span about ±70 mm)
    vol = MeasurementVolume(half_x_near_mm=40.0, half_x_far_mm=40.0)
    T = rig.true_body("probe")
    xs = (rig.tools["probe"] @ T[:3, :3].T + T[:3, 3])[:, 0]
    assert (np.abs(xs) <= 40).any() and (np.abs(xs) > 40).any()  # the premise
    with PolarisMock(rig, ROMS, clock=FAST, volume=vol) as m:
        with NDITracker(m.start_pty(), ROMS, **FAST_OPTS) as tr:
            s = tr.read().tools["probe"]
    assert s.partially_out_of_volume and not s.out_of_volume and s.pose is not None
    assert s.port_status == 0x31 | 0x80 and not s.usable


# --- the mock's state machine, command by command -----------------------------------------------

def test_state_machine_error_codes(mock: PolarisMock) -> None:
    assert err(mock, "PHSR", "00") == 0x10            # before INIT
    assert err(mock, "FOO") == 0x01                   # unknown command
    r = mock.handle_line(b"INIT:0000")
    assert r == p.encode_error(0x04)                  # bad CRC
    assert err(mock, "INIT") is None
    assert err(mock, "TX", "0801") == 0x0C            # tracking command before TSTART
    assert err(mock, "BX", "0801") == 0x0C
    assert err(mock, "TSTOP") == 0x0C
    assert err(mock, "PINIT", "05") == 0x08           # unknown handle
    assert err(mock, "COMM", "90000") == 0x06
    h = p.decode_phrq(cmd(mock, "PHRQ", "*********1****").text)
    assert err(mock, "PINIT", f"{h:02x}") == 0x0D     # no tool data yet
    assert err(mock, "PENA", f"{h:02X}D") == 0x0E     # not initialised
    rom = Path(ROMS["probe"]).read_bytes()
    for addr, chunk in p.rom_chunks(rom, pad_to=1024):  # ndicapi style: 16 chunks
        assert err(mock, "PVWR", p.pvwr_params(h, addr, chunk)) is None
    assert err(mock, "PINIT", f"{h:02x}") is None     # lowercase handle accepted
    assert mock.handles == {h: "probe"}
    assert err(mock, "PENA", f"{h:02X}X") == 0x09     # bad priority
    assert cmd(mock, "PHSR", "03").text == f"01{h:02X}011"
    assert err(mock, "PENA", f"{h:02X}D") is None
    assert cmd(mock, "PHSR", "04").text == f"01{h:02X}031"
    assert cmd(mock, "PHINF", f"{h:02X}0001").text.endswith("31")
    assert err(mock, "TSTART") is None
    assert err(mock, "TSTART") == 0x0C
    assert err(mock, "PHSR", "00") == 0x0C            # not allowed while tracking
    assert err(mock, "PHINF", f"{h:02X}0001") == 0x0C
    assert err(mock, "INIT") == 0x0C
    assert err(mock, "TX", "0002") == 0x23            # unmodelled reply option
    assert err(mock, "TSTOP") is None
    assert err(mock, "PHF", f"{h:02X}") is None
    assert mock.handles == {}


def test_mock_system_commands(mock: PolarisMock) -> None:
    ver = cmd(mock, "VER", "0").text
    assert "\nFreeze Tag: Polaris Spectra Rev 007\n" in ver
    assert cmd(mock, "BEEP", "2").text == "1"
    assert cmd(mock, "APIREV").text == "G.001.005"
    assert cmd(mock, "GETINFO", "Features.Firmware.Version").text.startswith(
        "Features.Firmware.Version=")
    # space form (no CRC) is answered with a CRC
    assert mock.handle_line(b"INIT ") == b"OKAYA896\r"
    vicra = PolarisMock(make_rig(), model="vicra")
    assert "Polaris Vicra Rev 007" in cmd(vicra, "VER", "0").text and vicra.rate_hz == 20.0
    with pytest.raises(ValueError):
        PolarisMock(make_rig(), model="aurora")
    with pytest.raises(ValueError):
        PolarisMock(make_rig(), {"nose": ROMS["marker"]})
    with pytest.raises(ValueError):
        mock.start_tcp("0.0.0.0")


def _load_all(m: PolarisMock, order=("marker", "probe")) -> dict[str, int]:
    cmd(m, "INIT")
    out = {}
    for name in order:
        h = p.decode_phrq(cmd(m, "PHRQ", "*********1****").text)
        for addr, chunk in p.rom_chunks(Path(ROMS[name]).read_bytes()):
            cmd(m, "PVWR", p.pvwr_params(h, addr, chunk))
        cmd(m, "PINIT", f"{h:02X}")
        cmd(m, "PENA", f"{h:02X}D")
        out[name] = h
    return out


def test_unknown_rom_falls_back_to_order_of_loading(rig: SimRig, tmp_path: Path) -> None:
    other = tmp_path / "other.rom"
    other.write_bytes(b"\x07" * 100)
    with PolarisMock(rig, ROMS, clock=FAST) as m:
        cmd(m, "INIT")
        h = p.decode_phrq(cmd(m, "PHRQ", "*********1****").text)
        cmd(m, "PVWR", p.pvwr_params(h, 0, other.read_bytes()[:64]))
        cmd(m, "PINIT", f"{h:02X}")
        assert m.handles[h] == "marker"
    with PolarisMock(rig, None, clock=FAST) as m:  # no ROM files at all: order of loading
        hs = _load_all(m, ("probe", "marker"))
        assert m.handles == {hs["probe"]: "marker", hs["marker"]: "probe"}


class ManualClock:
    """A real-time-like clock whose time the test sets (no sleeping, no flakiness)."""

    fast = False

    def __init__(self) -> None:
        self.t = 100.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += seconds


def test_frame_counter_real_time_and_same_frame_same_pose() -> None:
    rig = make_rig(Noise(fiducial_sigma_mm=0.2))
    clock = ManualClock()
    m = PolarisMock(rig, ROMS, clock=clock)  # type: ignore[arg-type]
    hs = _load_all(m)
    cmd(m, "TSTART", "80")
    a = p.decode_bx(cmd(m, "BX", "0801")).by_handle()[hs["marker"]]
    b = p.decode_bx(cmd(m, "BX", "0801")).by_handle()[hs["marker"]]
    assert a.frame == b.frame == 0 and a.translation_mm == b.translation_mm  # same frame
    clock.t += 1.5 / 60.0
    c = p.decode_bx(cmd(m, "BX", "0801")).by_handle()[hs["marker"]]
    assert c.frame == 1 and c.translation_mm != a.translation_mm  # new noisy observation
    clock.t += 1.0
    assert p.decode_bx(cmd(m, "BX", "0801")).frame == 61
    cmd(m, "TSTOP")
    cmd(m, "TSTART", "80")  # resets the counter
    assert p.decode_bx(cmd(m, "BX", "0801")).frame == 0


def test_fast_clock_advances_once_per_request(mock: PolarisMock) -> None:
    _load_all(mock)
    cmd(mock, "TSTART", "80")
    frames = [p.decode_tx(cmd(mock, "TX", "0801").text).frame for _ in range(3)]
    frames += [p.decode_bx(cmd(mock, "BX", "0801")).frame]
    assert frames == [1, 2, 3, 4]


def test_faults_are_reproducible(rig: SimRig) -> None:
    def run() -> list[bytes | None]:
        m = PolarisMock(rig, ROMS, clock=FAST, seed=11,
                        faults=PolarisFaults(crc_error_prob=0.3, drop_reply_prob=0.2,
                                             missing_fraction=0.3))
        _load_all(m)
        cmd(m, "TSTART", "80")
        return [m.handle_line(b"TX 0801") for _ in range(40)]
    a, b = run(), run()
    assert a == b
    assert any(r is None for r in a)
    bad = 0
    for r in a:
        if r is not None:
            try:
                p.split_reply(r)
            except ProtocolError:
                bad += 1
    assert bad > 0
    with pytest.raises(ValueError):
        PolarisFaults(crc_error_prob=1.5)


def test_reconnect_to_a_device_left_tracking(mock: PolarisMock) -> None:
    """A host that died mid-run leaves the Polaris tracking; no break reaches it over TCP, so
    INIT answers ERROR0C and the driver must TSTOP first."""
    ep = mock.start_tcp()
    first = NDITracker(ep, ROMS, **FAST_OPTS).open()
    first._ser.close()  # the link drops without TSTOP (as after kill -9)
    assert mock.state == "tracking"
    with NDITracker(ep, ROMS, **FAST_OPTS) as tr:
        assert tr.read().tools["marker"].usable
    assert "TSTOP:" in mock.commands
