"""Pose selection for force-torque self-calibration (tmscal.calib.selfcal.design) and the
simulation study (tmscal.calib.selfcal.study.simulate): the observability indices against hand
computations, DETMAX never worse than its start and at the brute-force optimum on small pools,
the greedy selections, the candidate pool, and the study on small seeded pools."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tmscal.calib.selfcal.design import (
    INDICES,
    candidate_pool,
    detmax,
    log_det,
    observability,
    scale_columns,
    select_by_index,
)
from tmscal.calib.selfcal.model import UR5E
from tmscal.calib.selfcal.study.simulate import SELECTIONS, simulate, stages, wrench_noise

from ..fuzz import fuzz_settings


def _diag_J(sv: list[float], rows: int) -> np.ndarray:
    J = np.zeros((rows, len(sv)))
    J[np.arange(len(sv)), np.arange(len(sv))] = sv
    return J


def _pool(seed: int, N: int, L: int, r: int = 6) -> np.ndarray:
    """Random Jacobian blocks with columns of very different scales (as mm and rad mix)."""
    rng = np.random.default_rng(seed)
    return rng.normal(size=(N, r, L)) * np.exp(2 * rng.normal(size=L))


# --- observability indices ---------------------------------------------------------------------

def test_indices_of_a_diagonal_jacobian_by_hand():
    sv = [8.0, 2.0, 1.0, 0.5]
    o = observability(_diag_J(sv, 18), m=3)
    assert o["O1"] == pytest.approx((8 * 2 * 1 * 0.5) ** (1 / 4) / math.sqrt(3), rel=1e-12)
    assert o["O2"] == pytest.approx(0.5 / 8, rel=1e-12)
    assert o["O3"] == pytest.approx(0.5, rel=1e-12)
    assert o["O4"] == pytest.approx(0.25 / 8, rel=1e-12)
    assert o["O5"] == pytest.approx(1 / (1 / 8 + 1 / 2 + 1 + 2), rel=1e-12)


def test_o1_is_the_geometric_mean_its_exponent_is_one_over_L():
    """Scaling J by c scales O1 by c (the geometric mean of L singular values); with the
    exponent 1/m that public code uses it would scale by c^(L/m)."""
    J = np.random.default_rng(1).normal(size=(12, 5))  # m = 2 configurations, L = 5
    c = 3.0
    assert observability(c * J, 2)["O1"] == pytest.approx(c * observability(J, 2)["O1"],
                                                         rel=1e-12)
    sv = np.linalg.svd(J, compute_uv=False)
    assert observability(J, 2)["O1"] == pytest.approx(
        math.exp(np.mean(np.log(sv))) / math.sqrt(2), rel=1e-12)


def test_o1_in_log_space_does_not_underflow():
    sv = [1e-3] * 400   # the product 1e-1200 underflows a double
    o = observability(_diag_J(sv, 402), m=67)
    assert o["O1"] == pytest.approx(1e-3 / math.sqrt(67), rel=1e-9)


def test_indices_on_rank_deficient_jacobians_are_zero():
    J = np.random.default_rng(2).normal(size=(30, 6))
    J[:, 5] = J[:, 0] - 2 * J[:, 3]                      # a dependent column
    assert observability(J, 5) == {k: 0.0 for k in INDICES}
    assert observability(_diag_J([3.0, 2.0, 0.0], 6), 1) == {k: 0.0 for k in INDICES}
    wide = np.random.default_rng(3).normal(size=(6, 10))  # fewer rows than parameters
    assert observability(wide, 1) == {k: 0.0 for k in INDICES}


def test_indices_are_taken_on_J_not_on_JtJ():
    sv = [4.0, 1.0]
    o = observability(_diag_J(sv, 6), 1)
    assert o["O3"] == pytest.approx(1.0)       # σ_L of J; of JᵀJ it would be 1 too, so:
    assert o["O2"] == pytest.approx(0.25)      # JᵀJ would give 1/16
    assert o["O1"] == pytest.approx(2.0)       # JᵀJ would give 4


def test_scale_columns_unit_norm_and_zero_column_kept():
    J = np.random.default_rng(4).normal(size=(12, 4)) * [1e3, 1.0, 1e-3, 0.0]
    J[:, 3] = 0.0
    Js, h = scale_columns(J)
    assert np.allclose(np.linalg.norm(Js[:, :3], axis=0), 1.0)
    assert h[3] == 1.0 and np.all(Js[:, 3] == 0)
    assert np.allclose(Js / h, J)


def test_observability_refuses_bad_input():
    with pytest.raises(ValueError, match="2-D"):
        observability(np.zeros(5), 1)
    with pytest.raises(ValueError, match="m = 0"):
        observability(np.eye(3), 0)


# --- DETMAX ------------------------------------------------------------------------------------

@given(seed=st.integers(0, 2**32 - 1), N=st.integers(12, 60), L=st.integers(2, 9),
       k=st.integers(1, 12))
@fuzz_settings(examples=40)
def test_detmax_never_worse_than_its_start(seed, N, L, k):
    """Random pools (columns of mixed scales), random starts — rank-deficient ones included
    when k·6 < L or by chance."""
    B = _pool(seed, N, L)
    k = min(k, N - 1)
    start = np.random.default_rng(seed + 1).choice(N, k, replace=False)
    got = detmax(B, k, start=start)
    assert len(got) == k and len(set(got.tolist())) == k and got.min() >= 0 and got.max() < N
    assert log_det(B, got) >= log_det(B, start)


@pytest.mark.parametrize("seed", range(5))
def test_detmax_reaches_the_brute_force_optimum_on_small_pools(seed):
    B = _pool(seed, N=14, L=5, r=2)
    k = 4
    best = max(log_det(B, list(c)) for c in itertools.combinations(range(14), k))
    assert log_det(B, detmax(B, k)) == pytest.approx(best, abs=1e-9)
    start = np.random.default_rng(seed).choice(14, k, replace=False)
    assert log_det(B, detmax(B, k, start=start)) == pytest.approx(best, abs=1e-9)


def test_detmax_improves_a_random_design_of_a_realistic_size():
    B = _pool(7, N=600, L=20)
    start = np.random.default_rng(7).choice(600, 40, replace=False)
    got = detmax(B, 40, start=start)
    assert log_det(B, got) > log_det(B, start) + 1.0


def test_detmax_selection_is_invariant_to_column_scaling():
    B = _pool(8, N=80, L=6)
    scaled = B * np.array([1e4, 1.0, 1e-4, 3.0, 1.0, 0.1])
    assert np.array_equal(detmax(B, 10), detmax(scaled, 10))


def test_detmax_refuses_bad_arguments():
    B = _pool(9, N=20, L=4)
    with pytest.raises(ValueError, match="cannot select 21"):
        detmax(B, 21)
    with pytest.raises(ValueError, match="distinct"):
        detmax(B, 3, start=[1, 1, 2])
    with pytest.raises(ValueError, match="non-finite"):
        detmax(np.full((5, 6, 2), np.nan), 2)


# --- greedy selection by index ---------------------------------------------------------------

@pytest.mark.parametrize("index", INDICES)
def test_greedy_selection_by_an_index_beats_random_designs_on_it(index):
    B = _pool(10, N=300, L=8)
    k = 20
    sel = select_by_index(B, k, index, rng=0)
    assert len(set(sel.tolist())) == k

    def value(idx):
        Js, _ = scale_columns(B[idx].reshape(-1, B.shape[2]))
        return observability(Js, k)[index]

    gen = np.random.default_rng(11)
    randoms = [value(gen.choice(300, k, replace=False)) for _ in range(20)]
    assert value(sel) > np.median(randoms)


def test_select_by_index_refuses_an_unknown_index():
    with pytest.raises(ValueError, match="O6"):
        select_by_index(_pool(0, 20, 3), 5, "O6")


# --- candidate pool ------------------------------------------------------------------------------

def test_candidate_pool_within_joint_limits():
    q = candidate_pool(UR5E.joint_limits_rad, 2000, rng=0)
    lim = UR5E.joint_limits_rad
    assert q.shape == (2000, 6)
    assert np.all(q >= lim[:, 0]) and np.all(q <= lim[:, 1])
    # uniform: every joint's range is covered end to end
    span = (q.max(axis=0) - q.min(axis=0)) / (lim[:, 1] - lim[:, 0])
    assert np.all(span > 0.99)


def test_candidate_pool_refuses_bad_limits():
    with pytest.raises(ValueError, match="lower limit"):
        candidate_pool(np.array([[1.0, 0.0]]), 3)
    with pytest.raises(ValueError, match="finite"):
        candidate_pool(np.array([[0.0, np.inf]]), 3)


# --- the simulation study ----------------------------------------------------------------------

def test_wrench_noise_bounded_and_of_the_stated_spread():
    rng = np.random.default_rng(0)
    x = wrench_noise(rng, 20000, 1.0, 0.2)
    assert np.all(np.abs(x[:, :3]) <= 1.0) and np.all(np.abs(x[:, 3:]) <= 0.2)
    # σ = bound/3, truncated at 3σ (which shrinks σ by ~1.5 %); 20000 draws: ±2 % is > 5 SE
    assert np.std(x[:, :3]) == pytest.approx(1 / 3, rel=0.04)
    avg = wrench_noise(rng, 5000, 1.0, 0.2, samples=100)
    assert np.std(avg[:, 3:]) == pytest.approx(0.2 / 3 / 10, rel=0.06)


def test_simulate_without_noise_recovers_what_the_wrench_sees():
    # errors on every parameter the wrench sees (alone or in a combination): noise-free, the
    # identification recovers all of it but the split of confounded offsets, which on the
    # UR5e moves the TCP far less than the errors did
    res = simulate(errors="seen", pool=300, k=30, seed=1, force_n=1e-6, torque_nm=1e-7,
                   samples=1, compare=False, trials=1)
    assert res.before_absorbed["mean_mm"] > 3.0
    assert res.after_absorbed["mean_mm"] < res.before_absorbed["mean_mm"] / 3


def test_simulate_protocols_put_errors_where_they_say():
    kw = {"pool": 300, "k": 30, "seed": 2, "compare": False, "trials": 1, "samples": 10}
    paper = simulate(errors="paper", **kw)
    assert set(paper.in_error) == {n for n in paper.identifiable
                                   if n != "mg" and not n.startswith(("f0_", "t0_"))}
    assert "base_yaw" not in paper.identifiable and "a_2" not in paper.identifiable
    seen = simulate(errors="seen", **kw)
    assert {"theta0_3", "theta0_4", "sensor_roll", "sensor_yaw"} <= set(seen.in_error)
    assert "a_2" not in seen.in_error and "theta0_1" not in seen.in_error
    every = simulate(errors="all", **kw)
    assert {"a_2", "d_1", "theta0_1", "base_x", "base_yaw"} <= set(every.in_error)
    assert "mg" not in every.in_error and "f0_x" not in every.in_error
    assert "floor" not in every.to_dict()
    # link lengths the wrench cannot see stay wrong: what the hand/eye cannot absorb remains
    assert every.after_absorbed["mean_mm"] > 0.5
    assert every.after_absorbed["mean_mm"] < every.before_absorbed["mean_mm"]


def test_simulate_runs_on_medrue_whose_lengths_the_wrench_sees():
    res = simulate(arm="medrue", errors="all", pool=300, k=30, seed=3, compare=False,
                   trials=1)
    assert {"L11", "L12", "L22"} <= set(res.identifiable)
    assert res.parameters == 47
    assert res.after_absorbed["mean_mm"] < res.before_absorbed["mean_mm"] / 2


def test_simulate_compares_every_selection_and_reports_stages():
    seen: list[str] = []
    res = simulate(pool=200, k=20, seed=4, trials=1, samples=10, progress=seen.append)
    assert list(res.indices) == list(SELECTIONS)
    assert seen == stages(True)
    for d in res.indices.values():
        assert set(d["after"]) == {"mean_mm", "max_mm", "sd_mm"}
        assert set(d["observability"]) == set(INDICES)
    # DETMAX maximises det(JᵀJ): no other selection's design has a larger one
    best = res.indices["detmax"]["log_det"]
    assert all(d["log_det"] <= best + 1e-9 for d in res.indices.values())


def test_simulate_refuses_bad_settings():
    with pytest.raises(ValueError, match="fewer than the pool"):
        simulate(pool=100, k=100)
    with pytest.raises(ValueError, match="errors"):
        simulate(errors="some")
    with pytest.raises(ValueError, match="unknown arm"):
        simulate(arm="kuka")
    with pytest.raises(ValueError, match="equations"):
        simulate(pool=100, k=2)
