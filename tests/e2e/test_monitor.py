"""``tmscal monitor`` end to end: a mock DENSO arm and a mock Polaris (in this process, over
loopback TCP) serving the simulated TMS rig on the FAST clock, ``tmscal monitor`` in a child
process, and ``pyigtl.OpenIGTLinkClient`` (as a navigation program connects) receiving its
STATUS messages. The STATUS body is decoded here from the OpenIGTLink specification (code
uint16, subcode int64, error name char[20], zero-terminated string), not with tmscal's packer.

Nothing depends on wall-clock timing: on the fast clock the rig's time is the tracker's
virtual time (frames served / 60 Hz), which is also the monitor's clock, so a ``mock.events``
bump at 5 s comes at frame 300 of the run however fast the frames are read; the monitor reads
a fixed number of frames (``--frames``) and waits for the client before the first.
"""

from __future__ import annotations

import json
import re
import struct
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from tests.rigs import point_config, write_config
from tmscal.config import load_config
from tmscal.mocks.launch import start_mock_rig
from tmscal.sim import tms_rig_truth
from tmscal.timing import Deadline

pyigtl = pytest.importorskip("pyigtl")

pytestmark = pytest.mark.e2e

BUMP_AT_S = 5.0
FRAMES = 540  # 9 s of tracker time at 60 Hz


class _Status(pyigtl.MessageBase):
    """A STATUS message as the OpenIGTLink specification lays it out; every one received is
    kept in ``RECEIVED`` (pyigtl's client keeps only the latest message per device)."""

    RECEIVED: list[tuple[int, str, str]] = []
    LOCK = threading.Lock()

    def __init__(self) -> None:
        super().__init__()
        self._message_type = "STATUS"

    def _unpack_content(self, content: bytes) -> None:
        code, _sub, name = struct.unpack(">Hq20s", content[:30])
        text = content[30:].split(b"\0", 1)[0].decode("utf-8")
        with self.LOCK:
            self.RECEIVED.append((code, name.rstrip(b"\0").decode(), text))


@pytest.fixture(autouse=True)
def _status_reader(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setitem(pyigtl.messages.message_type_to_class_constructor, "STATUS", _Status)
    _Status.RECEIVED.clear()
    yield


@pytest.fixture(scope="module")
def calib_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``tmscal solve -o`` (QR36, with its noise model) of 200 simulated poses of the mock's
    rig (the built-in TMS rig truth, the paper's noise, seed 3)."""
    from tmscal.session import make_header, records_from_arrays, write_session
    from tmscal.sim import Noise, simulate

    d = tmp_path_factory.mktemp("monitor-calib")
    truth, sim = simulate(200, np.random.default_rng(3), noise=Noise(), truth=tms_rig_truth())
    header = make_header(["marker", "probe"], truth=truth.as_dict())
    write_session(d / "s.jsonl", header,
                  records_from_arrays(sim["A"], sim["marker"], sim["probe"], sim["commanded"]))
    out = d / "calib.yaml"
    r = subprocess.run([sys.executable, "-m", "tmscal.cli", "solve", str(d / "s.jsonl"), "-o",
                        str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture
def rig(tmp_path: Path):
    """start(events) → (config pointing at the running mocks, the running mock rig)."""
    started: list = []

    def start(events: list | None = None):
        cfg = write_config(tmp_path, "mock-denso-polaris.yaml",
                           mock={"clock": "fast", "seed": 7, "truth": "tms",
                                 "events": events or [],
                                 "noise": {"fiducial_sigma_mm": 0.05, "robot_rot_sigma_deg":
                                           0.05, "robot_trans_sigma_mm": 0.05},
                                 "tracker": {"model": "spectra"}, "robot": {}})
        mr = start_mock_rig(load_config(cfg), tracker_transport="tcp")
        started.append(mr)
        return point_config(cfg, mr.endpoints), mr
    yield start
    for mr in started:
        mr.close()


def _start(cfg: Path, calib: Path, *extra: str) -> tuple[subprocess.Popen, object]:
    """``tmscal monitor`` in a child process on a free port, waiting for a client; returns
    (process, a connected pyigtl client)."""
    proc = subprocess.Popen([sys.executable, "-m", "tmscal.cli", "monitor", str(cfg), "--calib",
                             str(calib), "--port", "0", "--wait-client", "60", "--json",
                             *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    line = proc.stderr.readline()  # type: ignore[union-attr]
    m = re.search(r"OpenIGTLink STATUS server on 127\.0\.0\.1:(\d+)", line)
    if m is None:
        proc.kill()
        raise AssertionError(f"monitor did not start: {line!r} {proc.communicate()!r}")
    return proc, pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=int(m.group(1)))


def _received(pred, seconds: float = 30.0) -> list[tuple[int, str, str]]:
    """The STATUS messages received, once one satisfies ``pred`` (bounded wait: the client's
    thread takes them off the socket)."""
    d = Deadline(seconds)
    while True:
        with _Status.LOCK:
            got = list(_Status.RECEIVED)
        if any(pred(s) for s in got) or d.expired():
            return got
        d.remaining()  # the client runs in its own thread
        threading.Event().wait(0.01)


def _events(out: str) -> list[dict]:
    return [json.loads(ln) for ln in out.splitlines() if ln.strip()]


def test_a_tracker_bump_raises_the_alarm_sends_status_and_stops_the_robot(rig, calib_file):
    cfg, mr = rig([{"at_s": BUMP_AT_S, "move": "tracker", "mm": [0.6, 0.0, 0.8],
                    "deg": [0.0, 0.0, 0.0]}])
    proc, client = _start(cfg, calib_file, "--frames", str(FRAMES), "--stop-robot")
    try:
        out, err = proc.communicate(timeout=240)
        got = _received(lambda s: "what moved" in s[2])
    finally:
        client.stop()
    assert proc.returncode == 3, err
    ev = _events(out)
    alarms = [e for e in ev if e["event"] == "alarm"]
    assert len(alarms) == 1, ev
    a = alarms[0]
    # the bump (1 mm of the tracker) shows in both bodies' residuals at its size
    for body in ("marker", "probe"):
        assert 0.8 < a["residual"][body]["mm"] < 1.2, a
    # reported within 1 s of tracker time after the bump (the mock's fast clock: frames / 60)
    assert BUMP_AT_S < a["t_s"] <= BUMP_AT_S + 1.0, a
    assert a["robot_stopped"] is True
    # then what moved: at one pose a tracker move and a coil re-seat are the same change,
    # either is named (with the other as the runner-up)
    dx = [e for e in ev if e["event"] == "diagnosis"]
    assert len(dx) == 1 and ev.index(dx[0]) == ev.index(a) + 1, ev
    assert dx[0]["changed"] in ("tracker", "coil"), dx[0]["diagnosis"]
    assert dx[0]["candidates"][0] == "tracker" and "coil" in dx[0]["candidates"], dx[0]
    assert 0.8 < dx[0]["diagnosis"]["delta_mm"] < 1.2, dx[0]["diagnosis"]
    assert mr.devices[1].stats["halts"] == 1  # the DENSO mock saw one Robot_Halt
    assert ev[-1]["event"] == "summary" and ev[-1]["alarms"] == 1
    # the navigation's client got the alarm as a STATUS message (code 2: error)
    status = [s for s in got if s[1] == "RigChanged"]
    assert [s[2].startswith("ALARM") for s in status] == [True, False], got
    assert all(s[0] == 2 for s in status) and "what moved" in status[1][2], got
    assert (1, "", "tmscal monitor: watching") in got


def test_a_quiet_session_raises_nothing(rig, calib_file):
    cfg, mr = rig()
    proc, client = _start(cfg, calib_file, "--frames", str(FRAMES), "--stop-robot")
    try:
        out, err = proc.communicate(timeout=240)
        got = _received(lambda s: s[2] == "tmscal monitor: watching")
    finally:
        client.stop()
    assert proc.returncode == 0, err
    ev = _events(out)
    assert [e["event"] for e in ev] == ["summary"], ev
    s = ev[0]
    assert s["alarms"] == 0 and s["frames"] == FRAMES
    # the still phase is checked from settle_s (1 s) + the warm-up (1 s) on: most frames
    assert s["checked"] > FRAMES / 2, s
    assert mr.devices[1].stats["halts"] == 0
    assert got and got[0] == (1, "", "tmscal monitor: watching")


def test_a_tool_out_of_view_is_reported(rig, calib_file):
    """The probe leaves the view at 2 s (moved 1.4 m sideways on the coil: outside the
    Spectra's volume); it is reported after --out-of-view seconds, not as an alarm."""
    cfg, mr = rig([{"at_s": 2.0, "move": "coil_centre", "mm": [1000.0, 1000.0, 0.0],
                    "deg": [0.0, 0.0, 0.0]}])
    proc, client = _start(cfg, calib_file, "--frames", "360", "--out-of-view", "1.5")
    try:
        out, err = proc.communicate(timeout=240)
        got = _received(lambda s: s[1] == "ToolOutOfView")
    finally:
        client.stop()
    assert proc.returncode == 0, err
    ev = _events(out)
    gone = [e for e in ev if e["event"] == "out_of_view"]
    assert len(gone) == 1 and gone[0]["tool"] == "probe", ev
    assert 3.4 < gone[0]["t_s"] < 3.6, gone  # 2 s + 1.5 s, to a frame or two
    assert not [e for e in ev if e["event"] == "alarm"], ev
    assert any(s[0] == 4 and s[1] == "ToolOutOfView" for s in got), got


def test_devices_that_disappear_are_a_clear_error(rig, calib_file):
    cfg, mr = rig()
    proc, client = _start(cfg, calib_file)  # until stopped: the devices go away under it
    try:
        _received(lambda s: s[2] == "tmscal monitor: watching")
        mr.close()
        out, err = proc.communicate(timeout=120)
    finally:
        client.stop()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, (out, err)
    assert re.search(r"^error: the monitor lost the (tracker|robot) \((ndi|denso)\): .+; "
                     r"nothing is being checked any more$", err.strip().splitlines()[-1]), err
