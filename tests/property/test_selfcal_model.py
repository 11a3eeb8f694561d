"""Properties of the self-calibration arm model for any joint values and any perturbed arm:
forward kinematics gives rigid 4×4 poses; the gravity force the sensor reads (bias removed)
has magnitude m·g; the torque (bias removed) is the centre of gravity crossed with it."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.calib.selfcal.model import G_STANDARD, NOMINAL, forward, perturb, wrench

angles = st.floats(-2 * math.pi, 2 * math.pi, allow_nan=False)
joints = st.lists(angles, min_size=7, max_size=7)   # sliced to the arm's joints
arms = st.sampled_from(sorted(NOMINAL))
seeds = st.integers(0, 2**32 - 1)


def arm(name: str, seed: int):
    """The nominal arm with ±5 mm / ±5° on every length and angle (base and sensor included),
    a tool of 0.2–5 kg with its centre of gravity within ±150 mm and a random bias."""
    rng = np.random.default_rng(seed)
    model = perturb(NOMINAL[name], rng, length_mm=5.0, angle_deg=5.0)
    p = model.vector()
    names = model.parameter_names()
    p[names.index("mg")] = rng.uniform(0.2, 5.0) * G_STANDARD
    for k in ("cog_x", "cog_y", "cog_z"):
        p[names.index(k)] = rng.uniform(-150.0, 150.0)
    for k in ("f0_x", "f0_y", "f0_z", "t0_x", "t0_y", "t0_z"):
        p[names.index(k)] = rng.uniform(-3.0, 3.0)
    return model.with_vector(p)


@fuzz_settings(100)
@given(arms, seeds, st.lists(joints, min_size=1, max_size=4))
def test_forward_is_rigid(name, seed, q):
    model = arm(name, seed)
    T = forward(model, np.array(q)[:, :model.n_joints])
    R = T[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_array_equal(T[:, 3, :], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (len(q), 4)))
    assert np.all(np.isfinite(T))


@fuzz_settings(100)
@given(arms, seeds, st.lists(joints, min_size=1, max_size=4))
def test_wrench_is_the_tool_weight_plus_bias(name, seed, q):
    model = arm(name, seed)
    w = wrench(model, np.array(q)[:, :model.n_joints])
    f = w[:, :3] - model.bias[:3]
    tau = w[:, 3:] - model.bias[3:]
    mg = model.tool_mass_kg * G_STANDARD
    np.testing.assert_allclose(np.linalg.norm(f, axis=1), mg, rtol=1e-12)
    # τ = c × f: perpendicular to both, |τ| = |c| |f| sin(angle)
    c_m = model.tool_cog_mm * 1e-3
    np.testing.assert_allclose(tau @ c_m, 0.0, atol=1e-12 * mg)
    np.testing.assert_allclose(np.einsum("ij,ij->i", tau, f), 0.0, atol=1e-10 * mg * mg)
    cos = f @ c_m / (mg * max(np.linalg.norm(c_m), 1e-300))
    np.testing.assert_allclose(np.linalg.norm(tau, axis=1),
                               np.linalg.norm(c_m) * mg * np.sqrt(np.clip(1 - cos ** 2, 0, 1)),
                               atol=1e-9 * mg)
