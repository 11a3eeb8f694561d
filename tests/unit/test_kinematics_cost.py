"""The kinematic estimate's cost (issue 30, "Linear cost"): no dense factorisation of an array
that grows with the poses in both dimensions (the m × m singular vectors that made it n²), the
identifiability analysis's reduction of the data Jacobian, the cross-validation folds' warm
start, and the progress it reports (the CLI's bar). Timing is benchmarks/kinematics.py
--cost's, never a test's.

Poses 4×4 mm (A = base_from_flange, B/C = tracker_from_marker/probe), joints rad.
"""

from __future__ import annotations

import io
from typing import Any

import numpy as np
import pytest

from tmscal.calib import solve
from tmscal.calib.kinematics import arm_by_name, base_from_flange
from tmscal.calib.kinematics import estimate as est
from tmscal.calib.kinematics.identifiability import identifiability
from tmscal.cli.progress import FitBar
from tmscal.geometry import make_pose, matrix_from_rotvec, random_rotation

HOME = np.array([np.pi, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])
NOISE = {"robot_sigma_mm": 0.05, "robot_sigma_deg": 0.03, "tracker_sigma_mm": 0.025,
         "tracker_sigma_deg": 0.05}


def _noisy(T: np.ndarray, rng: np.random.Generator, mm: float, deg: float) -> np.ndarray:
    R = np.stack([matrix_from_rotvec(w) for w in rng.normal(0, np.radians(deg), (len(T), 3))])
    out = T.copy()
    out[:, :3, :3] = T[:, :3, :3] @ R
    out[:, :3, 3] += rng.normal(0, mm, (len(T), 3))
    return out


def _rig(n: int, seed: int = 5):
    """A UR5e with deviations of the default tolerance on every 'full' parameter, random X,
    Y, Z, n configurations around the home, the tracker's and the robot's noise."""
    rng = np.random.default_rng(seed)
    chain0 = arm_by_name("ur5e")
    names = est.level_parameters(chain0, "full")
    true = chain0.with_deviations(names, rng.normal(0, 1, len(names))
                                  * est.prior_sigmas(names, est.Tolerances()))
    X = make_pose(random_rotation(rng), rng.uniform(-50, 50, 3))
    Y = make_pose(random_rotation(rng), rng.uniform(-50, 50, 3))
    Z = make_pose(random_rotation(rng), rng.uniform(500, 1500, 3))
    q = HOME + rng.uniform(-0.6, 0.6, (n, 6))
    A = _noisy(base_from_flange(true, q), rng, 0.05, 0.03)
    B = _noisy(np.linalg.inv(Z) @ A @ X, rng, 0.025, 0.05)
    C = _noisy(np.linalg.inv(Z) @ A @ Y, rng, 0.025, 0.05)
    s = solve(base_from_flange(chain0, q), B, C, method="qr36")
    return chain0, q, [B, C], ([s.X, s.Y], s.Z)


def test_no_factorisation_grows_with_the_poses_in_both_dimensions(monkeypatch) -> None:
    """Every SVD, QR, eigendecomposition, inverse and Cholesky factor of the whole estimate
    (level auto: every level, the noise estimate, the folds, the identifiability analysis)
    has at least one dimension below the number of poses n: nothing is (m × m) in the
    m = 12 n residuals, so the cost is linear in n (the dense m × m singular vectors of the
    null-space analysis were the n² of issue 30)."""
    chain0, q, bodies, start = _rig(60)
    n = len(q)
    seen: list[tuple[str, tuple[int, ...]]] = []

    def spy(name: str, fn: Any) -> Any:
        def wrapped(*args: Any, **kwargs: Any) -> Any:
            out = fn(*args, **kwargs)
            for x in [args[0], *(out if isinstance(out, tuple) else (out,))]:
                a = np.asarray(x)
                if a.ndim >= 2:
                    seen.append((name, a.shape))
            return out
        return wrapped

    for name in ("svd", "qr", "eigh", "inv", "pinv", "cholesky", "lstsq", "solve"):
        monkeypatch.setattr(np.linalg, name, spy(name, getattr(np.linalg, name)))
    res = est.estimate_kinematics(q, bodies, chain0, start, NOISE)
    assert res.fit.level in est.LEVELS and seen
    big = [(nm, s) for nm, s in seen if s[-1] >= n and s[-2] >= n]
    assert not big, f"factorisations with both dimensions ≥ {n} poses: {big[:5]}"


def test_identifiability_depends_on_the_rows_only_through_their_inner_products() -> None:
    """The analysis reduces the data Jacobian to its thin QR's R: the same Jacobian with its
    rows doubled and scaled by 1/√2 (the same JᵀJ, twice the rows) gives the same
    combinations, singular values and estimates."""
    chain0, q, bodies, start = _rig(30)
    fit = est.fit_kinematics(q, bodies, chain0, "full", start, NOISE)
    prob = est._Problem(q, bodies, chain0, fit.names, est.prior_sigmas(fit.names,
                                                                     est.Tolerances()),
                        est._whitener_for([fit.X, fit.Y], fit.noise_used, len(q)))
    s = est._State([fit.X, fit.Y], fit.Z, fit.delta)
    _, J = prob.evaluate(s)
    assert J is not None
    Jd = J[:fit.m]
    args = (fit.names, prob.tau, fit.delta)
    a = identifiability(*args, Jd, prob.n_xyz, 2, False)
    b = identifiability(*args, np.concatenate([Jd, Jd]) / np.sqrt(2), prob.n_xyz, 2, False)
    assert [len(x) for x in a] == [len(x) for x in b]
    assert sum(len(x) for x in a) == len(fit.names)
    for xa, xb in zip(a, b, strict=True):
        for ca, cb in zip(xa, xb, strict=True):
            assert ca.reason == cb.reason
            assert ca.sigma_data == pytest.approx(cb.sigma_data, rel=1e-8, abs=1e-9)
        # the same subspace for each reason (within one, the basis is a choice)
        for why in {c.reason for c in xa}:
            Va = _orth([c.vector for c in xa if c.reason == why])
            Vb = _orth([c.vector for c in xb if c.reason == why])
            np.testing.assert_allclose(Va @ Va.T, Vb @ Vb.T, atol=1e-6)
    ident = [(c.estimate, c.sd) for c in a[0]], [(c.estimate, c.sd) for c in b[0]]
    np.testing.assert_allclose(ident[0], ident[1], rtol=1e-6, atol=1e-9)


def _orth(vs: list[Any]) -> np.ndarray:
    U, _, _ = np.linalg.svd(np.array(vs).T, full_matrices=False)
    return U


def test_a_warm_start_reaches_the_fit_from_the_start() -> None:
    """A fold's fit started from the fit on all poses (``warm``) is the fit started from the
    linear start with zero deviations: the same minimum, in fewer iterations."""
    chain0, q, bodies, start = _rig(40)
    full = est.fit_kinematics(q, bodies, chain0, "full", start, NOISE)
    keep = np.arange(40) % 5 != 2
    sub = [N[keep] for N in bodies]
    cold = est.fit_kinematics(q[keep], sub, chain0, "full", start, full.noise_used,
                              noise_mode="given")
    warm = est.fit_kinematics(q[keep], sub, chain0, "full", start, full.noise_used,
                              noise_mode="given", warm=full, identify=False)
    assert warm.iterations < cold.iterations
    assert warm.chi2 == pytest.approx(cold.chi2, rel=1e-7)  # both stop at LM's ftol
    np.testing.assert_allclose(warm.delta / est.prior_sigmas(warm.names, est.Tolerances()),
                               cold.delta / est.prior_sigmas(cold.names, est.Tolerances()),
                               atol=1e-5)
    np.testing.assert_allclose(warm.X, cold.X, atol=1e-6)
    np.testing.assert_allclose(warm.Z, cold.Z, atol=1e-5)
    assert cold.identified and not (warm.identified or warm.weak or warm.unidentified)
    with pytest.raises(est.CalibrationError, match="warm start"):
        est.fit_kinematics(q[keep], sub, chain0, "offsets", start, NOISE, warm=full)


def test_progress_counts_every_fit_in_order() -> None:
    """Level auto reports its 3 levels on all poses and each level's k folds: ``done`` never
    falls, the total is 3 (1 + k), the last call says all are done, and the LM iterations
    of each fit are reported by name."""
    chain0, q, bodies, start = _rig(30)
    calls: list[tuple[int, int, str]] = []
    est.estimate_kinematics(q, bodies, chain0, start, NOISE, folds=5,
                            progress=lambda d, t, w: calls.append((d, t, w)))
    done = [c[0] for c in calls]
    assert {c[1] for c in calls} == {3 * (1 + 5)}
    assert done == sorted(done) and done[0] == 0 and done[-1] == 18
    whats = " | ".join(c[2] for c in calls)
    for lv in est.LEVELS:
        assert f"{lv}, all 30 poses: LM iteration 1" in whats
        assert f"{lv}, fold 5/5: done" in whats
    calls.clear()
    est.estimate_kinematics(q, bodies, chain0, start, NOISE, level="offsets",
                            progress=lambda d, t, w: calls.append((d, t, w)))
    assert calls[-1] == (1, 1, "offsets, all 30 poses: done")


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_fit_bar_draws_on_a_terminal_and_not_elsewhere() -> None:
    tty, pipe = _Tty(), io.StringIO()
    for stream in (tty, pipe):
        bar = FitBar("solve", stream=stream)
        bar(0, 18, "kinematics: none, all 30 poses")
        bar(7, 18, "kinematics: offsets, fold 2/5: LM iteration 3, cost 2845")
        bar.close()
    assert "7/18 fits" in tty.getvalue() and "offsets, fold 2/5" in tty.getvalue()
    assert pipe.getvalue() == ""
