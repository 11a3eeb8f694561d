"""The resume checks every kind of run shares (``tmscal.acquisition.resume``) and what a
self-calibration resume re-derives (``selfcal.rederive_poses``), without devices: where the
arm may rest (position and orientation: near P0, or on the straight line and slerp from the
last commanded pose to the next), the header's plan against the re-derived one, and the
self-calibration header's configurations against the candidates drawn again from its seed.
Poses base_from_flange 4×4 mm, joints rad, angles deg."""

from __future__ import annotations

import copy
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from tmscal.acquisition.devices import envelope_for
from tmscal.acquisition.resume import (
    RESUME_TOLERANCE_DEG,
    RESUME_TOLERANCE_MM,
    check_recorded,
    check_same_plan,
    check_where_run_stopped,
    rotation_to_path,
)
from tmscal.acquisition.selfcal import (
    SelfcalPlan,
    nominal_arm,
    nominal_poses,
    plan_selfcal,
    rederive_poses,
)
from tmscal.config import load_config
from tmscal.errors import SessionError
from tmscal.session import PoseRecord
from tmscal.sim import TMS_RIG_P0
from tmscal.sim.arm import make_arm

from ..rigs import CONFIGS


def _pose(R: Rotation, t) -> np.ndarray:
    P = np.eye(4)
    P[:3, :3], P[:3, 3] = R.as_matrix(), t
    return P


def test_rotation_to_path_is_the_distance_to_the_slerp():
    """Against scipy's Slerp sampled 20× finer, for random orientation pairs and points:
    within the stated 0.25°."""
    rng = np.random.default_rng(22)
    for _ in range(50):
        a, b, h = Rotation.random(3, random_state=rng)
        ref = Slerp([0, 1], Rotation.concatenate([a, b]))(np.linspace(0, 1, 7201))
        want = np.degrees((ref.inv() * h).magnitude().min())
        got = rotation_to_path(h.as_matrix(), a.as_matrix(), b.as_matrix())
        assert want - 1e-9 <= got <= want + 0.25, (want, got)


#: a plan of two poses 300 mm and 90° apart, P0 the built-in rig's
P0 = TMS_RIG_P0
R0 = Rotation.from_matrix(P0[:3, :3])
PLAN = np.stack([_pose(R0 * Rotation.from_euler("x", 45, degrees=True), P0[:3, 3] + [150, 0, 0]),
                 _pose(R0 * Rotation.from_euler("x", -45, degrees=True),
                       P0[:3, 3] + [-150, 0, 0])])


@pytest.mark.parametrize("here, done", [
    (P0, set()), (P0, {0}),                                           # near P0
    (_pose(R0 * Rotation.from_euler("z", 15, degrees=True), P0[:3, 3] + [30, 20, 0]), {0}),
    (PLAN[0], {0}), (PLAN[1], {0}),                                   # the ends of the path
    (_pose(R0 * Rotation.from_euler("x", 22.5, degrees=True), P0[:3, 3] + [75, 0, 0]), {0}),
    (_pose(R0 * Rotation.from_euler("x", -30, degrees=True), P0[:3, 3] + [-100, 30, 0]),
     {0}),                                                            # on the way, near it
])
def test_an_arm_near_p0_or_on_the_path_may_resume(here, done):
    check_where_run_stopped(here, PLAN, P0, done, "s.jsonl")


@pytest.mark.parametrize("here, done, said", [
    # at P0's position, turned past the tolerance: before the first pose and after
    (_pose(R0 * Rotation.from_euler("z", 25, degrees=True), P0[:3, 3]), set(),
     "0.0 mm and 25.0° from the session's P0"),
    (_pose(R0 * Rotation.from_euler("y", 100, degrees=True), P0[:3, 3]), {0},
     "0.0 mm and 100.0° from the session's P0"),
    # on the straight line from pose 0 to pose 1, turned off the slerp about another axis
    (_pose(R0 * Rotation.from_euler("x", 22.5, degrees=True)
           * Rotation.from_euler("z", 30, degrees=True), P0[:3, 3] + [75, 0, 0]), {0},
     "and 30.0° from the path where the run stopped"),
    # the orientation of the path, 60 mm off it
    (_pose(R0, P0[:3, 3] + [0, 60, 0]), {0}, "60.0 mm and 0.0° from the path"),
])
def test_an_arm_moved_or_turned_away_is_refused(here, done, said):
    with pytest.raises(SessionError, match="Nothing was moved") as e:
        check_where_run_stopped(here, PLAN, P0, done, "s.jsonl")
    assert said in str(e.value) and "\n" not in str(e.value)
    assert f"tolerance {RESUME_TOLERANCE_MM:g} mm and {RESUME_TOLERANCE_DEG:g}°" in str(e.value)


def test_a_pose_that_is_not_a_number_is_refused():
    here = P0.copy()
    here[0, 3] = np.nan
    with pytest.raises(SessionError):
        check_where_run_stopped(here, PLAN, P0, set(), "s.jsonl")


def test_the_header_plan_must_be_the_rederived_one():
    check_same_plan(PLAN, PLAN + 1e-9, "s.jsonl", "pose", "the config")
    moved = PLAN.copy()
    moved[1, 0, 3] += 0.01
    with pytest.raises(SessionError, match=r"s.jsonl: pose 1 of the header's plan is at "
                                           r"\[350\.0, 0\.0, 400\.0\] mm, but the plan "
                                           r"re-derived from the config puts it at"):
        check_same_plan(moved, PLAN, "s.jsonl", "pose", "the config")
    with pytest.raises(SessionError, match="has 1 poses; the plan re-derived .* has 2"):
        check_same_plan(PLAN[:1], PLAN, "s.jsonl", "pose", "the config")


def test_every_recorded_pose_was_commanded_where_the_plan_says():
    recs = [PoseRecord(index=i, A=None, B=None, C=None, commanded=PLAN[i].copy(),
                       skipped="x") for i in range(2)]
    check_recorded(recs, lambda r: PLAN[r.index], "s.jsonl", "pose")
    check_recorded(recs, lambda r: None, "s.jsonl", "pose")       # the plan does not say
    recs[1].commanded[2, 3] += 1.0
    with pytest.raises(SessionError, match="pose 1 was commanded to .* but the plan puts it"):
        check_recorded(recs, lambda r: PLAN[r.index], "s.jsonl", "pose")


# --- self-calibration: what a resume draws again -------------------------------------------

@pytest.fixture(scope="module")
def selfcal():
    """A plan of 8 configurations of the nominal UR5e from 300 candidates, made as a run
    makes it (around the mock's home configuration, inside the mock rig's envelope)."""
    model = nominal_arm("ur5e")
    q0 = np.array(make_arm("ur5e", "paper", 5).home_q)
    p0 = nominal_poses(model, q0)[0]
    cfg = load_config(CONFIGS / "mock-ur-ati.yaml", check_files=False)
    plan = plan_selfcal(model, q0, p0, envelope_for(cfg, p0), 8, 300, 3, 90.0)
    return model, plan


def _header_plan(plan: SelfcalPlan, **changes) -> SelfcalPlan:
    h = copy.deepcopy(plan.to_header())
    h.update(changes)
    return SelfcalPlan.from_header({"selfcal": h})


def test_a_plan_rederives_to_its_own_poses(selfcal):
    model, plan = selfcal
    again = _header_plan(plan)
    assert again.q0 is not None and np.array_equal(again.q0, plan.q0)
    poses, notes = rederive_poses(again, model, "s.jsonl")
    np.testing.assert_allclose(poses, plan.poses, atol=1e-9)
    assert notes == []


def test_a_header_without_q0_is_checked_but_not_drawn_again(selfcal):
    """A session from before q0_rad was recorded: the limits and the forward kinematics are
    checked, and a note says the draw was not."""
    model, plan = selfcal
    h = copy.deepcopy(plan.to_header())
    del h["q0_rad"]
    old = SelfcalPlan.from_header({"selfcal": h})
    poses, notes = rederive_poses(old, model, "s.jsonl")
    np.testing.assert_allclose(poses, plan.poses, atol=1e-9)
    assert len(notes) == 1 and "no q0_rad" in notes[0]


@pytest.mark.parametrize("change, said", [
    ({"seed": 4}, "configuration 0 of the header is none of the 300 candidates drawn from "
                  "its seed 4"),
    ({"span_deg": 45.0}, "is none of the 300 candidates"),
    ({"pool": 200}, "is none of the 200 candidates"),
])
def test_a_different_draw_is_refused(selfcal, change, said):
    model, plan = selfcal
    with pytest.raises(SessionError, match="the header was edited or belongs to another run") \
            as e:
        rederive_poses(_header_plan(plan, **change), model, "s.jsonl")
    assert said in str(e.value)


def test_edited_configurations_are_refused(selfcal):
    model, plan = selfcal
    q = plan.q.copy()
    q[3] = q[2]
    with pytest.raises(SessionError, match="configurations 2 and 3 of the header are the same "
                                           "candidate"):
        rederive_poses(_header_plan(plan, q_rad=q.tolist()), model, "s.jsonl")
    q = plan.q[::-1].copy()
    with pytest.raises(SessionError, match="not in the nearest-neighbour order"):
        rederive_poses(_header_plan(plan, q_rad=q.tolist(), poses=plan.poses[::-1].tolist()),
                       model, "s.jsonl")
    q = plan.q.copy()
    q[1, 0] = np.radians(400)
    with pytest.raises(SessionError, match=r"configuration 1 of the header puts joint 1 at "
                                           r"400\.0°, outside arm 'ur5e'"):
        rederive_poses(_header_plan(plan, q_rad=q.tolist()), model, "s.jsonl")


@pytest.mark.parametrize("change", [
    {"pool": 10**12}, {"pool": True}, {"pool": 5}, {"seed": -1}, {"seed": 1.5},
    {"span_deg": 0}, {"span_deg": 720}, {"q0_rad": [0.0, 1.0]}, {"q0_rad": [float("nan")] * 6}])
def test_a_header_draw_out_of_range_is_a_session_error(selfcal, change):
    """A pool of 10¹² candidates would be drawn on resume: refused as the header is read."""
    _, plan = selfcal
    with pytest.raises(SessionError, match="the header's 'selfcal' plan is incomplete or "
                                           "invalid"):
        _header_plan(plan, **change)


@pytest.mark.parametrize("arm, header_arm, said", [
    ("vs060", "ur5e", "the session was recorded for arm 'ur5e'; arm='vs060' was given"),
    (None, "kuka_kr6", "the header's selfcal.arm"),
])
def test_a_resume_needs_the_sessions_arm(tmp_path, selfcal, arm, header_arm, said):
    """The header's arm is the nominal model its poses are re-derived on: an unknown one, or
    another named by --arm, is refused."""
    from tmscal.acquisition.selfcal import SelfcalStrategy
    from tmscal.session import SessionWriter, make_header, read_session

    _, plan = selfcal
    path = tmp_path / "sc.jsonl"
    with SessionWriter.create(path, make_header(["ft"], selfcal={**plan.to_header(),
                                                                 "arm": header_arm})):
        pass
    strategy = SelfcalStrategy(load_config(CONFIGS / "mock-ur-ati.yaml", check_files=False),
                               arm=arm)
    strategy.read(read_session(path))
    with pytest.raises(SessionError, match=re.escape(said)):
        strategy.rederive(read_session(path))
