"""The stopping rule of the re-registration at the rig (``tmscal.acquisition.reregister``,
docs/lab-day.md, "Re-registering at the rig"), fed simulated sessions one pose at a time as the
engine would: a moved tracker stops at the target once the update is determined, never before
its minimum poses; a marker knocked as well is refused only when two poses in a row refuse;
the poses it takes are well spread. The changes are applied here to the recorded tracker poses
(the tracker moved by D sees every tool through D), not by the code under test."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from tmscal.acquisition.progress import Progress
from tmscal.acquisition.reregister import (
    REFUSALS_TO_STOP,
    ReregisterSettings,
    ReregisterStrategy,
)
from tmscal.calib import diagnose as dg
from tmscal.check import noise_of
from tmscal.cli import main
from tmscal.config import load_config
from tmscal.errors import CalibrationError
from tmscal.formats.calibfile import read_calibration
from tmscal.geometry import angle_between, make_pose, rot_x
from tmscal.poses import PlanSpec
from tmscal.session import Session, read_session
from tmscal.sim import TMS_RIG_P0

D = make_pose(rot_x(np.radians(1.0)), [3.0, 0.0, 0.0])   # the tracker's move
K = make_pose(rot_x(np.radians(0.3)), [0.5, 0.0, 0.0])   # the marker knocked on the coil


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    d = tmp_path_factory.mktemp("rereg")
    for args in (["simulate", "-o", d / "all.jsonl", "--poses", 70, "--seed", 4,
                  "--samples", 10],):
        r = CliRunner().invoke(main, [str(a) for a in args])
        assert r.exit_code == 0, r.output
    s = read_session(d / "all.jsonl")
    from tmscal.session import write_session
    write_session(d / "calib.jsonl", s.header, s.poses[:60])
    r = CliRunner().invoke(main, ["solve", str(d / "calib.jsonl"), "-o", str(d / "cal.yaml"),
                                  "--folds", "2"])
    assert r.exit_code == 0, r.output
    cf = read_calibration(d / "cal.yaml")
    return cf, s.header, s.poses[60:70]


def _strategy(mock_config, cf, target_mm=0.5, max_poses=10) -> ReregisterStrategy:
    cfg = load_config(mock_config("mock-ur-polaris.yaml"))
    st = ReregisterStrategy(cfg, cf.calibration, noise_of(cf, ("marker", "probe")),
                            ReregisterSettings(("z",), target_mm=target_mm,
                                               max_poses=max_poses))
    st._use(PlanSpec.from_config(cfg.plan, TMS_RIG_P0, 200))
    return st


def _feed(st: ReregisterStrategy, header, poses) -> int:
    """Hand the strategy the session one pose more each time, as the engine does; the number
    of poses when it stopped."""
    st.begin(Session(header, []))
    for k in range(len(poses) + 1):
        if st.next(Session(header, [replace(p, index=i) for i, p in enumerate(poses[:k])]),
                   Progress()) is None:
            return k
    return len(poses)


def test_a_moved_tracker_stops_at_the_target_after_the_minimum(rig, mock_config) -> None:
    cf, header, poses = rig
    moved = [replace(p, B=D @ p.B, C=D @ p.C) for p in poses]
    st = _strategy(mock_config, cf)
    n = _feed(st, header, moved)
    assert st.stop == "target" and n >= dg.min_poses(("z",), True), (n, st.stop)
    assert st.spread is not None and st.spread["p95_mm"] <= 0.5
    tight = _strategy(mock_config, cf, target_mm=1e-4, max_poses=6)  # out of reach
    assert _feed(tight, header, moved) <= 6 and tight.stop == "max_poses"


def test_a_second_change_is_refused_only_when_it_persists(rig, mock_config,
                                                          monkeypatch) -> None:
    cf, header, poses = rig
    two = [replace(p, B=D @ p.B @ K, C=D @ p.C) for p in poses]
    st = _strategy(mock_config, cf)
    n = _feed(st, header, two)
    assert st.stop == "refused" and st.refusal is not None, st.stop
    assert n >= dg.min_poses(("z",), True) + REFUSALS_TO_STOP - 1
    monkeypatch.setattr("tmscal.acquisition.reregister.REFUSALS_TO_STOP", 1)
    once = _strategy(mock_config, cf)
    assert _feed(once, header, two) == n - (REFUSALS_TO_STOP - 1) and once.stop == "refused"


def test_the_poses_are_well_spread_and_inside_the_plan(mock_config, rig) -> None:
    cf, _, _ = rig
    st = _strategy(mock_config, cf, max_poses=5)
    assert len(st.poses) == 5
    P = st.poses
    cfg = load_config(mock_config("mock-ur-polaris.yaml"))
    pool = PlanSpec.from_config(cfg.plan, TMS_RIG_P0, 200).poses()
    # spread in position and rotation together, each in units of the pool's RMS from P0
    s_t = np.sqrt(np.mean(np.sum((pool[:, :3, 3] - TMS_RIG_P0[:3, 3]) ** 2, axis=1)))
    s_r = np.sqrt(np.mean(angle_between(TMS_RIG_P0, pool) ** 2))

    def closest(Q: np.ndarray) -> float:
        dt = np.linalg.norm(Q[:, None, :3, 3] - Q[None, :, :3, 3], axis=2) / s_t
        dr = angle_between(Q[:, None], Q[None, :]) / s_r
        return float(np.sqrt(dt ** 2 + dr ** 2)[np.triu_indices(len(Q), 1)].min())

    # farther apart than the plan's first five poses, every one of them a pose of the plan
    assert closest(P) > closest(pool[:5])
    assert all(np.min(np.abs(pool - p).reshape(len(pool), -1).max(axis=1)) < 1e-9 for p in P)
    assert float(np.degrees(angle_between(TMS_RIG_P0, P)).max()) <= cfg.plan.rotation_deg * 2


@pytest.mark.parametrize("kw,match", [({"target_mm": 0.0}, "target_mm"),
                                      ({"max_poses": 1}, "max_poses")])
def test_bad_settings_are_named(kw, match) -> None:
    with pytest.raises(ValueError, match=match):
        ReregisterSettings(("z",), **kw)
    with pytest.raises(CalibrationError, match="--update 'q'"):
        ReregisterSettings(("q",))
