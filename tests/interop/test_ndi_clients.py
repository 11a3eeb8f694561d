"""The UNMODIFIED third-party NDI clients (ndicapi's ``ndicapy`` and
scikit-surgerynditracker) against our Polaris mock over a pty, on the fast clock.

The mock runs in a forked child process: ndicapy's blocking calls (``ndiProbe``,
``ndiPVWRFromFile``) hold the GIL while they wait for the device, so a mock thread in the
same process could not answer them (exactly like a real device, the mock must be elsewhere).
The child serves a SimRig built exactly like the parent's copy, so the parent knows the truth.
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from tmscal.geometry import rotation_angle
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

pytestmark = pytest.mark.interop

TOOLS_DIR = Path(__file__).resolve().parents[2] / "configs" / "tools"
ROMS = {"marker": str(TOOLS_DIR / "marker-8700340.rom"),
        "probe": str(TOOLS_DIR / "probe-8700340.rom")}
SIGMA_MM = 0.05  # fiducial noise of the served rig
POS_TOL_MM = 0.5  # ≫ the pose noise of 4 spheres at σ = 0.05 mm, ≪ anything wrong
ROT_TOL_RAD = np.radians(0.5)


def _rig() -> SimRig:
    return SimRig(tms_rig_truth(), noise=Noise(fiducial_sigma_mm=SIGMA_MM),
                  rng=np.random.default_rng(5), start=TMS_RIG_P0)


def _serve(model: str, conn, stop) -> None:  # runs in the child process
    from tmscal.mocks.clock import FAST
    from tmscal.mocks.polaris import PolarisMock
    with PolarisMock(_rig(), ROMS, model=model, clock=FAST, seed=1) as m:
        conn.send(m.start_pty())
        stop.wait(120)  # bounded
        conn.send(list(m.commands))


class Served:
    def __init__(self, model: str) -> None:
        ctx = mp.get_context("fork")
        self._conn, child = ctx.Pipe()
        self._stop = ctx.Event()
        self._proc = ctx.Process(target=_serve, args=(model, child, self._stop), daemon=True)
        self._proc.start()
        assert self._conn.poll(20), "mock child did not start"
        self.path: str = self._conn.recv()
        self.commands: list[str] = []

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        if self._conn.poll(10):
            self.commands = self._conn.recv()
        self._proc.join(10)
        if self._proc.is_alive():  # pragma: no cover
            self._proc.kill()


@pytest.fixture
def spectra() -> Iterator[Served]:
    s = Served("spectra")
    yield s
    s.close()


@pytest.fixture
def vicra() -> Iterator[Served]:
    s = Served("vicra")
    yield s
    s.close()


def _check_pose(name: str, q: np.ndarray, t: np.ndarray) -> None:
    from tmscal.geometry import matrix_from_quaternion
    truth = _rig().true_body(name)
    np.testing.assert_allclose(t, truth[:3, 3], atol=POS_TOL_MM)
    R = matrix_from_quaternion(np.asarray(q, dtype=float))
    assert rotation_angle(R.T @ truth[:3, :3]) < ROT_TOL_RAD


def test_ndicapi_bx_and_tx(spectra: Served) -> None:
    ndicapy = pytest.importorskip("ndicapy", reason="ndicapi (ndicapy) is not installed")
    assert ndicapy.ndiProbe(spectra.path) == ndicapy.NDI_OKAY
    dev = ndicapy.ndiOpen(spectra.path)
    assert dev
    try:
        ndicapy.ndiCommand(dev, "INIT:")
        assert ndicapy.ndiGetError(dev) == ndicapy.NDI_OKAY
        assert "Freeze Tag: Polaris Spectra" in ndicapy.ndiVER(dev, 0)
        ndicapy.ndiCommand(dev, "COMM:50000")
        assert ndicapy.ndiGetError(dev) == ndicapy.NDI_OKAY
        handles = {}
        for name in ("marker", "probe"):
            ndicapy.ndiCommand(dev, "PHRQ:*********1****")
            h = ndicapy.ndiGetPHRQHandle(dev)
            assert ndicapy.ndiPVWRFromFile(dev, h, ROMS[name]) == 0
            handles[name] = h
        for h in handles.values():
            ndicapy.ndiCommand(dev, f"PINIT:{h:02x}")
            assert ndicapy.ndiGetError(dev) == ndicapy.NDI_OKAY
            ndicapy.ndiCommand(dev, f"PENA:{h:02x}D")
            assert ndicapy.ndiGetError(dev) == ndicapy.NDI_OKAY
        ndicapy.ndiCommand(dev, "TSTART:")
        assert ndicapy.ndiGetError(dev) == ndicapy.NDI_OKAY
        frames = []
        for kind in ("BX", "TX", "BX", "TX"):
            ndicapy.ndiCommand(dev, f"{kind}:0801")
            assert ndicapy.ndiGetError(dev) == ndicapy.NDI_OKAY
            get_t = getattr(ndicapy, f"ndiGet{kind}Transform")
            get_f = getattr(ndicapy, f"ndiGet{kind}Frame")
            for name, h in handles.items():
                tr = get_t(dev, bytes([h]))
                assert tr not in ("MISSING", "DISABLED"), f"{kind} {name}: {tr}"
                _check_pose(name, tr[0:4], tr[4:7])
                assert tr[7] == pytest.approx(0.1, abs=1e-3)  # RMS error the mock reports
            frames.append(get_f(dev, bytes([handles["marker"]])))
        assert frames == sorted(set(frames))  # one new frame per request on the fast clock
        ndicapy.ndiCommand(dev, "TSTOP:")
        assert ndicapy.ndiGetError(dev) == ndicapy.NDI_OKAY
    finally:
        ndicapy.ndiClose(dev)


@pytest.mark.parametrize("model,capture", [("vicra", "BX"), ("spectra", "TX")])
def test_scikit_surgery_nditracker(model: str, capture: str, request) -> None:
    pytest.importorskip("ndicapy", reason="ndicapi (ndicapy) is not installed")
    nditracker = pytest.importorskip("sksurgerynditracker.nditracker",
                                     reason="scikit-surgerynditracker is not installed")
    served: Served = request.getfixturevalue(model)
    tracker = nditracker.NDITracker({"tracker type": "polaris", "serial port": served.path,
                                     "romfiles": [ROMS["marker"], ROMS["probe"]]})
    try:
        tracker.start_tracking()
        for _ in range(3):
            handles, _times, frames, tracking, quality = tracker.get_frame()
            assert len(handles) == 2
            for name, T, qual in zip(("marker", "probe"), tracking, quality, strict=True):
                T = np.asarray(T)
                assert np.isfinite(T).all(), f"{name} missing"
                truth = _rig().true_body(name)
                np.testing.assert_allclose(T[:3, 3], truth[:3, 3], atol=POS_TOL_MM)
                assert rotation_angle(T[:3, :3].T @ truth[:3, :3]) < ROT_TOL_RAD
                assert qual == pytest.approx(0.1, abs=1e-3)
        tracker.stop_tracking()
    finally:
        tracker.close()
    served.close()
    sent = served.commands
    # scikit-surgerynditracker picks TX for "Polaris Spectra Rev 007", BX otherwise
    assert f"{capture}:0801" in sent and ({"BX", "TX"} - {capture}).pop() + ":0801" not in sent
    assert sent.count("PVWR:" + sent[sent.index("PHRQ:*********1****") + 1][5:]) == 1
    assert sum(c.startswith("PVWR:") for c in sent) == 32  # ndicapi pads to 1024 bytes
    assert "TSTOP:" in sent
