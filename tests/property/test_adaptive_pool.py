"""Every pose an adaptive selection can return lies inside the safety envelope: random envelopes
(tmscal.drivers.base.Envelope: offset, rotation, workspace box, tool points), random plans and
rig seeds; the candidate pool is checked with acquisition.plan.check_plan first, then the
bootstrap and choose_next pick poses on a simulated rig.
The limits are checked here by hand from the drawn numbers, never through ``Envelope``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import event, given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.acquisition.plan import check_plan
from tmscal.acquisition.sample import spread_of
from tmscal.calib import prediction as ad
from tmscal.drivers.base import Envelope
from tmscal.errors import SafetyError
from tmscal.geometry import pose_mean
from tmscal.poses import make_plan
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

TOOL_POINTS = np.array([[3.0, 5.0, 110.0], [63.0, 5.0, 110.0], [-57.0, 5.0, 110.0]])
TOL = 1e-6


def inside_by_hand(P: np.ndarray, lim: dict, tol: float = TOL) -> bool:
    """The drawn limits, computed directly: offset, rotation angle, box of flange and tools,
    each widened by ``tol`` (negative: narrowed; a band of ±TOL where either answer is
    fine)."""
    t = P[:3, 3]
    if np.linalg.norm(t - TMS_RIG_P0[:3, 3]) > lim["offset"] + tol:
        return False
    c = (np.trace(TMS_RIG_P0[:3, :3].T @ P[:3, :3]) - 1.0) / 2.0
    if math.degrees(math.acos(min(1.0, max(-1.0, c)))) > lim["rotation"] + tol:
        return False
    pts = np.vstack([t, TOOL_POINTS @ P[:3, :3].T + t])
    return bool(np.all(pts >= lim["lo"] - tol) and np.all(pts <= lim["hi"] + tol))


def select(pool: np.ndarray, env: Envelope, rig: SimRig, settings: ad.AdaptiveSettings
           ) -> list[int]:
    """An adaptive selection: the pool checked before anything moves, then the bootstrap and
    choose_next's poses measured on the rig until stop_reason stops it."""
    check_plan(pool, env)
    A, B, C, spreads = [], [], [], []
    used: list[int] = []

    def measure(i: int) -> None:
        used.append(i)
        rig.move_flange(pool[i])
        A.append(rig.reported_flange())
        rec: dict = {"spread": {}, "samples": {"B": 10, "C": 10}}
        for body, out in (("marker", B), ("probe", C)):
            obs = rig.observe(body, 10)
            out.append(pose_mean(obs))
            rec["spread"][body] = spread_of(obs, out[-1])
        spreads.append(rec)

    for i in ad.bootstrap_indices(pool, settings.bootstrap_poses(2), TMS_RIG_P0):
        measure(i)
    while True:
        pred = ad.predict(np.array(A), np.array(B), np.array(C), pool[:settings.region],
                          settings, spreads=spreads)
        if ad.stop_reason(pred, len(used), settings):
            return used
        avail = np.ones(len(pool), dtype=bool)
        avail[used] = False
        cost = ad.candidate_cost_s(rig.commanded, pool, 250.0, 1200.0, 0.5)
        measure(ad.choose_next(pred, pool, avail, cost)[0])


def pool_extent(pool: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray]:
    """The pool's largest offset (mm), rotation (deg), and box of flange and tool points."""
    t = pool[:, :3, 3]
    off = float(np.max(np.linalg.norm(t - TMS_RIG_P0[:3, 3], axis=1)))
    c = (np.einsum("ij,nij->n", TMS_RIG_P0[:3, :3], pool[:, :3, :3]) - 1.0) / 2.0
    rot = float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))).max())
    pts = np.concatenate([t, (np.einsum("nij,kj->nki", pool[:, :3, :3], TOOL_POINTS)
                              + t[:, None]).reshape(-1, 3)])
    return off, rot, pts.min(axis=0), pts.max(axis=0)


@fuzz_settings(examples=16)
@given(plan_seed=st.integers(0, 10_000), rig_seed=st.integers(0, 2**32 - 1),
       radius=st.floats(5.0, 150.0), rotation=st.floats(1.0, 15.0),
       f_off=st.floats(0.95, 1.6), f_rot=st.floats(0.95, 1.6),
       grow=st.lists(st.floats(-3.0, 50.0), min_size=6, max_size=6))
def test_every_selected_pose_is_inside_the_envelope(plan_seed: int, rig_seed: int,
                                                    radius: float, rotation: float,
                                                    f_off: float, f_rot: float,
                                                    grow: list[float]) -> None:
    pool = make_plan("eq14", TMS_RIG_P0, 40, plan_seed, radius, rotation)
    off, rot, lo, hi = pool_extent(pool)
    lim = {"offset": off * f_off, "rotation": rot * f_rot,
           "lo": lo - np.array(grow[:3]), "hi": hi + np.array(grow[3:])}
    env = Envelope(center=TMS_RIG_P0, max_offset_mm=lim["offset"],
                   max_rotation_deg=lim["rotation"], box_min_mm=tuple(lim["lo"]),
                   box_max_mm=tuple(lim["hi"]), tool_points_mm=TOOL_POINTS)
    rig = SimRig(tms_rig_truth(), Noise(), np.random.default_rng(rig_seed), start=TMS_RIG_P0)
    settings = ad.AdaptiveSettings(max_poses=6, pool=40, region=20)
    try:
        used = select(pool, env, rig, settings)
    except SafetyError:
        event("pool refused")
        assert not all(inside_by_hand(P, lim, -TOL) for P in pool)
        assert len(rig.moves) == 0
        return
    event("selection ran")
    assert len(used) == len(rig.moves) >= settings.bootstrap_poses(2)
    for i, cmd in zip(used, rig.moves, strict=True):
        assert inside_by_hand(pool[i], lim)
        assert np.array_equal(cmd, pool[i])


def test_a_pool_with_one_pose_outside_is_refused_before_anything_is_chosen() -> None:
    pool = make_plan("eq14", TMS_RIG_P0, 40, 3, 100.0, 10.0)
    d = np.linalg.norm(pool[:, :3, 3] - TMS_RIG_P0[:3, 3], axis=1)
    worst = int(np.argmax(d))
    env = Envelope(center=TMS_RIG_P0, max_offset_mm=float(d[worst]) - 0.5)
    rig = SimRig(tms_rig_truth(), Noise(), np.random.default_rng(0), start=TMS_RIG_P0)
    with pytest.raises(SafetyError, match=f"plan pose {worst} "):
        select(pool, env, rig, ad.AdaptiveSettings(max_poses=6, pool=40, region=20))
    assert len(rig.moves) == 0
