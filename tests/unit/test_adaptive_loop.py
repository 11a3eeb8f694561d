"""The adaptive loop's pieces without devices (docs/adaptive.md): its decisions are a function
of the session's records alone (what --resume relies on), skipped bootstrap poses are
replaced by the next well-spread ones, robot time is attributed to its phases, a resumed
session must name distinct pool poses, and the settings come from the config, the command
line and the session header with typed errors. The loop on the mock devices is in
tests/e2e/test_adaptive.py."""

from __future__ import annotations

import numpy as np
import pytest

from tmscal.acquisition import adaptive_run as loop
from tmscal.acquisition.engine import PhaseClock
from tmscal.acquisition.progress import Progress
from tmscal.acquisition.settings import sampling_settings as _settings
from tmscal.calib.prediction import AdaptiveSettings, bootstrap_indices
from tmscal.config import load_config
from tmscal.errors import ConfigError, SessionError
from tmscal.motion import move_duration
from tmscal.poses import PlanSpec
from tmscal.session import PoseRecord, Session, validate_record
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, tms_rig_truth
from tmscal.solving.predict import (
    adaptive_header,
    prediction_inputs,
    robot_time_of,
    settings_from_header,
)

from ..rigs import write_config

SPREAD = {"marker": {"trans_mm": 0.03, "rot_deg": 0.05},
          "probe": {"trans_mm": 0.03, "rot_deg": 0.05}}


@pytest.fixture
def cfg(tmp_path):
    return load_config(write_config(tmp_path, "mock-denso-polaris.yaml", robot={"port": 0},
                                    adaptive={"pool": 300, "region": 100, "max_poses": 12}))


def _pool(cfg) -> np.ndarray:
    return PlanSpec.from_config(cfg.plan, TMS_RIG_P0, cfg.adaptive.pool).poses()


def _measure(rig: SimRig, i: int, j: int, P: np.ndarray, skipped: bool = False) -> PoseRecord:
    """Pose i of a session at pool pose j, measured on the simulated rig (one noisy
    observation per body; the spreads and robot time are fixed numbers)."""
    rig.move_flange(P)
    rec = PoseRecord(index=i, A=rig.reported_flange(), B=rig.observe("marker"),
                     C=None if skipped else rig.observe("probe"), commanded=P, time=float(i),
                     samples={"A": 10, "B": 20, "C": 0 if skipped else 20}, spread=SPREAD,
                     skipped="probe usable in 0 of 20 frames" if skipped else None, pool=j,
                     robot_s={"moving": 0.5, "settling": 0.2, "sampling": 0.4})
    return validate_record(rec)


def _session(poses: list[PoseRecord]) -> Session:
    return Session(header={"bodies": ["marker", "probe"]}, poses=list(poses))


def test_decisions_are_a_function_of_the_recorded_poses(cfg):
    """A run driven step by step, then every prefix of its records decided afresh (as a
    resumed run does): the same next pool pose every time and the same stop at the end."""
    pool, settings = _pool(cfg), loop.settings_for(cfg, target_mm=0.02)
    st = _settings(cfg, None, None)
    rig = SimRig(tms_rig_truth(), noise=Noise(), rng=np.random.default_rng(3), start=TMS_RIG_P0)
    recs: list[PoseRecord] = []
    while True:
        s = loop._State.of(recs, TMS_RIG_P0)
        reason, j, _, _ = loop._decide(s, pool, TMS_RIG_P0, settings, cfg, st, _session(recs))
        if reason is not None:
            break
        recs.append(_measure(rig, len(recs), j, pool[j]))
    assert reason == "max_poses" and len(recs) == 12  # 0.02 mm: out of reach of 12 poses
    boot = bootstrap_indices(pool, settings.bootstrap_poses(2), TMS_RIG_P0)
    assert [r.pool for r in recs[:len(boot)]] == boot
    for k in (len(boot), 7, 11):
        s = loop._State.of(recs[:k], TMS_RIG_P0)
        again = loop._decide(s, pool, TMS_RIG_P0, settings, cfg, st, _session(recs[:k]))
        assert again[:2] == (None, recs[k].pool)


def test_a_skipped_bootstrap_pose_is_replaced_by_the_next_well_spread_one(cfg):
    pool, settings = _pool(cfg), loop.settings_for(cfg)
    st = _settings(cfg, None, None)
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)
    nb = settings.bootstrap_poses(2)
    boot = bootstrap_indices(pool, nb + 1, TMS_RIG_P0)
    recs = [_measure(rig, i, j, pool[j], skipped=(i == 1)) for i, j in enumerate(boot[:nb])]
    s = loop._State.of(recs, TMS_RIG_P0)
    assert s.used == nb - 1 and s.next_index == nb
    reason, j, pred, info = loop._decide(s, pool, TMS_RIG_P0, settings, cfg, st,
                                         _session(recs))
    assert (reason, j, pred, info) == (None, boot[nb], None, {"bootstrap": True})


def test_cost_is_the_trapezoidal_move_plus_the_measured_overhead(cfg):
    pool = _pool(cfg)[:5]
    st = _settings(cfg, None, None)
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)
    empty = loop._State.of([], TMS_RIG_P0)
    prior = cfg.sampling.settle_s + cfg.sampling.samples / cfg.tracker.frame_rate_hz
    v, a = cfg.robot.speed_mm_s, cfg.robot.accel_mm_s2
    want = [move_duration(TMS_RIG_P0, P, v, a) + prior for P in pool]
    np.testing.assert_allclose(loop._costs(pool, empty, cfg, st), want)
    recs = [_measure(rig, 0, 3, pool[3])]
    recs[0].robot_s = {"moving": 9.0, "settling": 0.25, "sampling": 1.5}
    s = loop._State.of(recs, TMS_RIG_P0)
    want = [move_duration(pool[3], P, v, a) + 1.75 for P in pool]
    np.testing.assert_allclose(loop._costs(pool, s, cfg, st), want)


def test_robot_time_goes_to_its_phase_and_reconnecting_is_not_robot_time():
    t = iter([0.0, 1.5, 1.75, 3.0, 10.0, 10.5, 11.0, 20.0])  # the phase reports' times (s)
    heard: list[str] = []

    class Heard(Progress):
        def phase(self, i: int, name: str) -> None:
            heard.append(name)

    clock = PhaseClock(Heard(), clock=lambda: next(t))
    for name in ("moving", "settling", "sampling", "reconnecting", "moving", "sampling"):
        clock(4, name)
    assert clock.take() == {"moving": 1.5 + 0.5, "settling": 0.25, "sampling": 1.25 + 0.5}
    assert heard == ["moving", "settling", "sampling", "reconnecting", "moving", "sampling"]
    assert clock.take() == {"moving": 0.0, "settling": 0.0, "sampling": 0.0}


def test_robot_time_of_a_session_sums_the_phases():
    recs = [PoseRecord(0, None, None, skipped="x", robot_s={"moving": 1.0, "sampling": 2.0}),
            PoseRecord(1, None, None, skipped="y"),
            PoseRecord(2, None, None, skipped="z", robot_s={"moving": 0.5, "settling": 0.25})]
    assert robot_time_of(recs) == {"moving": 1.5, "settling": 0.25, "sampling": 2.0,
                                   "total": 3.75}


def test_prediction_inputs_use_spreads_only_when_every_pose_has_them():
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)
    recs = [_measure(rig, i, i, TMS_RIG_P0) for i in range(3)]
    recs.append(_measure(rig, 3, 3, TMS_RIG_P0, skipped=True))
    A, B, C, opts = prediction_inputs(recs[::-1], ["marker", "probe"])
    assert A.shape == C.shape == (3, 4, 4) and len(opts["spreads"]) == 3
    np.testing.assert_array_equal(B, np.stack([r.B for r in recs[:3]]))
    recs[1].spread = {}
    assert prediction_inputs(recs, ["marker", "probe"])[3] == {}


def test_settings_from_config_and_command_line(cfg):
    s = loop.settings_for(cfg, target_mm=0.03, bootstrap=None)
    assert (s.target_mm, s.max_poses, s.pool, s.region, s.bootstrap) == (0.03, 12, 300, 100,
                                                                          None)
    with pytest.raises(ConfigError, match="adaptive.*bootstrap"):
        loop.settings_for(cfg, bootstrap=13)  # more than max_poses 12


def test_settings_from_the_header_with_overrides_noted():
    h = {"adaptive": adaptive_header(AdaptiveSettings(target_mm=0.04, max_poses=20))}
    s, notes = settings_from_header(h, AdaptiveSettings(), {"max_poses": 25,
                                                           "target_mm": None, "pool": 7})
    assert (s.target_mm, s.max_poses, s.pool) == (0.04, 25, 1000)
    assert notes == ["adaptive.max_poses 25 from the command line (the session was recorded "
                     "with 20)"]
    with pytest.raises(SessionError, match="no 'adaptive' entry"):
        settings_from_header({"plan": {}}, AdaptiveSettings())
    h["adaptive"]["region"] = 5000
    with pytest.raises(SessionError, match="'adaptive' entry is invalid.*region"):
        settings_from_header(h, AdaptiveSettings())


@pytest.mark.parametrize("pools, what", [([0, None], "names no pool pose"),
                                         ([0, 300], "names pool pose 300 of 300"),
                                         ([4, 4], "repeats pool pose 4")])
def test_a_resume_refuses_records_that_are_not_distinct_pool_poses(cfg, pools, what):
    pool = _pool(cfg)
    recs = [PoseRecord(i, None, None, skipped="x", commanded=pool[0], pool=j)
            for i, j in enumerate(pools)]
    with pytest.raises(SessionError, match=f"pose 1 {what}"):
        loop._check_pool_poses(_session(recs), pool)


def test_stop_messages_say_which_rule_stopped():
    s = AdaptiveSettings(target_mm=0.05, max_poses=40)

    class P:
        coil_mm = 0.0431

    assert loop.stop_message("target", P, s, 12) == (
        "predicted coil-placement error 0.0431 mm ≤ target 0.05 mm at 95 %")
    P.coil_mm = 0.081
    assert loop.stop_message("max_poses", P, s, 40) == (
        "reached max_poses 40 with predicted 0.081 mm > target 0.05 mm at 95 %")
    assert "not finished: 3 poses, no prediction" in loop.stop_message(None, None, s, 3)


def test_pool_and_robot_time_fields_round_trip_and_are_checked():
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)
    rec = _measure(rig, 0, 17, TMS_RIG_P0)
    assert (rec.pool, rec.robot_s["settling"]) == (17, 0.2)
    assert "pool" not in PoseRecord(0, rec.A, rec.B).to_json()  # old sessions: unchanged
    rec.robot_s = {"moving": -1.0}
    with pytest.raises(SessionError, match="pose 0: field 'robot_s'"):
        validate_record(rec)
    rec.robot_s, rec.pool = None, -2
    with pytest.raises(SessionError, match="pose 0: field 'pool'"):
        validate_record(rec)


@pytest.mark.parametrize("section, key", [({"target_mm": 0}, "target_mm"),
                                          ({"confidence": 1.0}, "confidence"),
                                          ({"max_poses": 2000}, "max_poses"),
                                          ({"pool": 50, "region": 60, "max_poses": 10},
                                           "region"),
                                          ({"bootstrap": "four"}, "bootstrap"),
                                          ({"pace": 1}, "pace")])
def test_a_bad_adaptive_section_is_a_config_error_naming_the_key(tmp_path, section, key):
    p = write_config(tmp_path, "mock-denso-polaris.yaml", adaptive=section)
    with pytest.raises(ConfigError, match=rf"line \d+: key 'adaptive\.{key}'"):
        load_config(p)
