"""The Cramér–Rao bound of the calibration for a session with known truth, the noise model of
a simulated rig in the terms of the ``ml`` solver, and the predicted coil-placement
uncertainty ``ml`` reports (docs/methods.md).

Frames and units as everywhere: A = base_from_flange, B = tracker_from_marker, C =
tracker_from_probe, X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker;
4×4, mm.

The bound is the inverse Fisher information of the linearised measurement model of
:mod:`tmscal.calib.ml_model` at the true parameters: F = Jᵀ S⁻¹ J, J the Jacobian of the residuals
of the noise-free tracker poses Z⁻¹ A_i W at the truth, S the per-pose residual covariance of
the robot and tracker noise. No unbiased estimator has a covariance below F⁻¹ (in the order
and units of ``parameter_names``: per transform a right rotation vector in rad, then a
translation offset in mm).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..geometry import orthonormalize, rotvec_from_matrix
from .ml_model import (
    G_STEP,
    STEPS,
    Problem,
    covariance_from_jacobian,
    noise_covariance,
    parameter_names,
    tracker_covs,
    undistort,
    whitener,
)

__all__ = ["crb", "tool_tracker_cov", "sim_noise_options", "translation_rms_bound",
           "uncertainty_at", "placement_error"]


def tool_tracker_cov(tool_mm: np.ndarray, fiducial_sigma_mm: float, samples: int = 1
                     ) -> np.ndarray:
    """Covariance (6×6, body frame, [rot rad; trans mm]) of a pose fitted by absolute
    orientation to k fiducials ``tool_mm`` (k, 3) with isotropic noise σ per coordinate,
    averaged over ``samples`` observations: rotation σ² (Σ |p|² I − p pᵀ)⁻¹ about the
    centroid, translation σ²/k I (the body origin at the centroid: uncorrelated)."""
    p = np.asarray(tool_mm, dtype=float)
    p = p - p.mean(axis=0)
    s2 = fiducial_sigma_mm ** 2 / max(int(samples), 1)
    M = np.sum(p * p) * np.eye(3) - p.T @ p
    cov = np.zeros((6, 6))
    cov[:3, :3] = s2 * np.linalg.inv(M)
    cov[3:, 3:] = s2 / len(p) * np.eye(3)
    return cov


def sim_noise_options(fiducial_sigma_mm: float, robot_rot_sigma_deg: float,
                      robot_trans_sigma_mm: float, tool_mm: np.ndarray, samples: int = 1
                      ) -> dict[str, Any]:
    """``ml`` options matching the simulated rig's noise (tmscal.sim.Noise): the rig turns the
    flange about a random axis by an angle ~ N(0, σ), i.e. σ/√3 per axis of the rotation
    vector; translation σ per component; the tracker as :func:`tool_tracker_cov`."""
    return {"robot_sigma_mm": robot_trans_sigma_mm,
            "robot_sigma_deg": robot_rot_sigma_deg / np.sqrt(3.0),
            "tracker_cov": tool_tracker_cov(tool_mm, fiducial_sigma_mm, samples)}


def crb(A: np.ndarray, B: np.ndarray | None, C: np.ndarray | None,
        truth: Mapping[str, np.ndarray | None], noise: Mapping[str, Any]) -> np.ndarray:
    """Cramér–Rao bound (covariance, parameters as ``parameter_names(bodies, "none")``) for
    robot poses A (n, 4, 4) and the truth {"X", "Z"[, "Y"]}; ``noise`` holds ``ml``'s noise
    options (robot_sigma_mm, robot_sigma_deg, and tracker_cov or tracker_sigma_mm and
    tracker_sigma_deg). The model is linearised at the noise-free tracker poses the truth
    gives, so B and C are not used beyond saying which bodies were measured: the probe
    counts when C is given and the truth has a "Y"."""
    A = np.asarray(A, dtype=float)
    if B is not None and len(B) != len(A):
        raise ValueError(f"crb: B has {len(B)} poses but A has {len(A)}")
    Ws = [np.asarray(truth["X"], dtype=float)]
    if C is not None and truth.get("Y") is not None:
        Ws.append(np.asarray(truth["Y"], dtype=float))
    Z = np.asarray(truth["Z"], dtype=float)
    bodies = [np.linalg.inv(Z) @ A @ W for W in Ws]
    names = ["marker", "probe"][:len(Ws)]
    opts = {"tracker_cov": None, "spreads": None, "tracker_sigma_mm": None,
            "tracker_sigma_deg": None, **dict(noise)}
    tracker = tracker_covs(len(A), names, opts)
    S = noise_covariance(Ws, float(opts["robot_sigma_mm"]),
                         float(np.radians(opts["robot_sigma_deg"])), tracker)
    prob = Problem(A, bodies, Ws, Z, "none")
    J = prob.jacobian(np.zeros(prob.n_params), whitener(S))
    return covariance_from_jacobian(J, "the calibration")


def translation_rms_bound(cov: np.ndarray, which: str = "Y", bodies: int = 2) -> float:
    """√(trace) of a transform's translation block of a bound from :func:`crb`: the smallest
    RMS translation error (mm) an unbiased method can have."""
    names = parameter_names(bodies, "none")
    idx = [names.index(f"{which}.t{a} (mm)") for a in "xyz"]
    return float(np.sqrt(np.trace(cov[np.ix_(idx, idx)])))


def placement_error(prob: Problem, th: np.ndarray, N_ref: np.ndarray, j: int
                     ) -> np.ndarray:
    """[rotation vector (rad, base), translation (mm)] of the body's pose when the robot is
    commanded with parameters θ to put body j at tracker pose N_ref, relative to where the
    estimate (θ = 0) puts it."""
    Ws, Z, G = prob.unpack(th)
    W0, Z0, G0 = prob.unpack(np.zeros_like(th))
    M = (prob.moments or [None] * len(Ws))[j]
    want = Z0 @ undistort(N_ref[None], G0, prob.model, M)[0]
    actual = orthonormalize(Z @ undistort(N_ref[None], G, prob.model, M)[0]
                            @ np.linalg.inv(Ws[j])) @ W0[j]
    rot = rotvec_from_matrix(actual[:3, :3] @ want[:3, :3].T)
    return np.concatenate([rot, actual[:3, 3] - want[:3, 3]])


@functools.lru_cache(maxsize=8)
def _squared_draws(d: int) -> np.ndarray:
    """40,000 draws of z² (z ~ N(0, I_d), fixed seed 0), drawn once per dimension."""
    z = np.random.default_rng(0).standard_normal((40_000, d))
    out = z * z
    out.flags.writeable = False
    return out


def _norm_quantile(cov: np.ndarray, q: float = 0.95) -> float:
    """q-quantile of ‖e‖ for e ~ N(0, cov) (Monte Carlo, 40,000 draws, fixed seed)."""
    lam = np.clip(np.linalg.eigvalsh(cov), 0.0, None)
    return float(np.quantile(np.sqrt(_squared_draws(len(lam)) @ lam), q))


def uncertainty_at(prob: Problem, P: np.ndarray, N_ref: np.ndarray, j: int
                   ) -> dict[str, Any]:
    """Predicted 1-σ (RMS) and 95 % radius of the position error (mm) and of the axis (z)
    error (deg) of body j when it is placed at tracker pose N_ref, from the covariance P."""
    k = len(P)
    Je = np.zeros((6, k))
    for i in range(k):
        h = G_STEP if i >= 6 * (len(prob.Ws) + 1) else STEPS[(i % 6) // 3]
        e = np.zeros(k)
        e[i] = h
        Je[:, i] = (placement_error(prob, e, N_ref, j)
                    - placement_error(prob, -e, N_ref, j)) / (2 * h)
    cov = Je @ P @ Je.T
    ct = cov[3:, 3:]
    _, Z0, G0 = prob.unpack(np.zeros(k))
    M = (prob.moments or [None] * len(prob.Ws))[j]
    axis = (Z0 @ undistort(N_ref[None], G0, prob.model, M)[0])[:3, 2]
    U = np.linalg.svd(np.eye(3) - np.outer(axis, axis))[0][:, :2]  # ⊥ the axis
    ca = np.degrees(1.0) ** 2 * (U.T @ cov[:3, :3] @ U)
    return {"position_mm": {"sigma": float(np.sqrt(np.trace(ct))), "p95": _norm_quantile(ct),
                            "covariance": ct},
            "axis_deg": {"sigma": float(np.sqrt(np.trace(ca))), "p95": _norm_quantile(ca)},
            "target": N_ref}
