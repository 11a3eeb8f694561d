"""The monitor's state machine (``tmscal.monitor.Monitor``) on frames built here from the
built-in TMS rig's truth, no devices and no clock: which frames the rule judges around a robot
move (settle before, latency after), a bump raising the alarm and the diagnosis, a tool out of
view, a calibration with an arm without joints. Tracker time is frame number / 60 Hz."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.drivers.base import ToolState, TrackerFrame
from tmscal.errors import CalibrationError
from tmscal.formats.calibfile import read_calibration
from tmscal.geometry import make_pose, matrix_from_rotvec
from tmscal.monitor import Monitor, MonitorSettings
from tmscal.sim import TMS_RIG_P0, tms_rig_truth
from tmscal.sim.changes import changed

RATE = 60.0


@pytest.fixture(scope="module")
def calib(tmp_path_factory: pytest.TempPathFactory):
    """A QR36 calibration file (with its noise model) of 200 simulated poses of the rig."""
    from tmscal.session import make_header, records_from_arrays, write_session
    from tmscal.sim import Noise, simulate

    d = tmp_path_factory.mktemp("monitor-loop")
    truth, sim = simulate(200, np.random.default_rng(3), noise=Noise(), truth=tms_rig_truth())
    write_session(d / "s.jsonl", make_header(["marker", "probe"], truth=truth.as_dict()),
                  records_from_arrays(sim["A"], sim["marker"], sim["probe"], sim["commanded"]))
    r = CliRunner().invoke(main, ["solve", str(d / "s.jsonl"), "-o", str(d / "c.yaml")])
    assert r.exit_code == 0, r.output
    return read_calibration(Path(d / "c.yaml"))


class Stream:
    """Frames of the rig at pose A with the tracker's frame noise (0.02 mm, 0.02° per axis)."""

    def __init__(self, seed: int = 0) -> None:
        self.truth = tms_rig_truth()
        self.rng = np.random.default_rng(seed)
        self.frame = 0
        self.A = TMS_RIG_P0.copy()
        self.hidden: set[str] = set()

    def _noisy(self, T: np.ndarray) -> np.ndarray:
        d = self.rng.normal(0, 0.02, 6)
        return T @ make_pose(matrix_from_rotvec(np.radians(d[3:])), d[:3])

    def next(self) -> TrackerFrame:
        self.frame += 1
        Zi = np.linalg.inv(self.truth.Z)
        tools = {}
        for b, F in (("marker", self.truth.X), ("probe", self.truth.Y)):
            if b in self.hidden:
                tools[b] = ToolState(None, missing=True)
            else:
                tools[b] = ToolState(self._noisy(Zi @ self.A @ F))
        return TrackerFrame(self.frame, self.frame / RATE, tools)


def _run(mon: Monitor, s: Stream, n: int, checked: list[int] | None = None,
         events: list | None = None, robot: np.ndarray | None = None) -> None:
    for _ in range(n):
        before = mon.checked
        evs = mon.step(s.next(), s.A if robot is None else robot)
        if checked is not None and mon.checked > before:
            checked.append(mon.last_checked)
        if events is not None:
            events += evs


def test_frames_are_judged_only_in_still_phases_with_settle_and_latency(calib):
    s = Stream()
    mon = Monitor(calib, ["marker", "probe"], RATE, MonitorSettings())
    checked: list[int] = []
    _run(mon, s, 300, checked)
    # from the first frame: 1 s settle (60 frames), then the 1 s warm-up of the frame noise
    assert min(checked) > 60
    s.A = s.A @ make_pose(None, [2.0, 0.0, 0.0])  # the robot moves at frame 301
    _run(mon, s, 200, checked)
    near = [f for f in checked if 301 - 6 <= f < 301 + 60]
    # neither the 0.1 s before the move (the latency: a report that late may belong to
    # them) nor the 1 s after it (the coil's swing) is judged
    assert near == [], near
    assert 301 - 7 in checked and 301 + 60 in checked
    assert mon.alarms == 0


def test_a_bump_raises_the_alarm_then_what_moved_and_clears_when_undone(calib):
    s = Stream(1)
    mon = Monitor(calib, ["marker", "probe"], RATE, MonitorSettings())
    ev: list = []
    _run(mon, s, 200, events=ev)
    assert ev == []
    s.truth = changed(s.truth, "tracker", [0.0, 0.8, 0.6])  # the tracker bumped by 1 mm
    _run(mon, s, 60, events=ev)
    assert [e.kind for e in ev] == ["alarm"]
    a = ev[0]
    assert 200 < a.frame <= 200 + 60  # within 1 s of the bump
    for b in ("marker", "probe"):
        assert 0.8 < a.details["residual"][b]["mm"] < 1.2
    dx = mon.diagnose_alarm()
    assert dx is not None and mon.diagnose_alarm() is None
    assert dx.details["changed"] in ("tracker", "coil")
    assert dx.details["candidates"][:1] == ["tracker"]
    s.truth = tms_rig_truth()  # undone: clears
    _run(mon, s, 120, events=ev)
    assert [e.kind for e in ev] == ["alarm", "clear"]
    assert mon.alarms == 1


def test_a_marker_moved_on_the_coil_is_named_from_one_pose(calib):
    s = Stream(2)
    mon = Monitor(calib, ["marker", "probe"], RATE, MonitorSettings())
    _run(mon, s, 200)
    s.truth = changed(s.truth, "marker", [0.0, 0.0, 0.0], [0.0, 0.6, 0.0])
    ev: list = []
    _run(mon, s, 60, events=ev)
    assert [e.kind for e in ev] == ["alarm"]
    # only the marker's residual moved
    assert ev[0].details["residual"]["probe"]["deg"] < 0.1
    assert mon.diagnose_alarm().details["changed"] == "marker"


def test_a_tool_out_of_view_is_reported_after_the_set_time_and_back(calib):
    s = Stream(3)
    mon = Monitor(calib, ["marker", "probe"], RATE, MonitorSettings(out_of_view_s=1.0))
    ev: list = []
    _run(mon, s, 120, events=ev)
    s.hidden = {"probe"}
    _run(mon, s, 120, events=ev)
    s.hidden = set()
    _run(mon, s, 30, events=ev)
    assert [(e.kind, e.details["tool"]) for e in ev] == [("out_of_view", "probe"),
                                                        ("in_view", "probe")]
    gone = ev[0]
    assert gone.frame == 120 + 61  # last seen at frame 120: more than 1 s later
    assert gone.details["why"] == "missing"
    assert mon.alarms == 0


def test_the_marker_is_required_and_an_arm_needs_the_joints(calib):
    with pytest.raises(CalibrationError, match="no 'marker'"):
        Monitor(calib, ["probe"], RATE)
    from dataclasses import replace

    class _Arm:  # any identified arm: the monitor asks for the joints before using it
        pass

    cf = replace(calib, calibration=replace(calib.calibration, arm=_Arm()))
    mon = Monitor(cf, ["marker"], RATE)
    with pytest.raises(CalibrationError, match="joints"):
        mon.step(Stream().next(), TMS_RIG_P0, None)
