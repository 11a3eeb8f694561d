"""Self-calibration figures that do not depend on the protocol (issue 21): the identification's
answer (``study.compare.canonical``) is the same whichever equivalent columns were kept, noise-free
wrenches give back exactly the combinations the wrench sees, the hand/eye absorption removes
rigid errors and nothing else, and the MedRUE model (Joubair et al. 2016) agrees with an
independent numeric solution of its loop closure."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import fsolve
from scipy.spatial.transform import Rotation

from tmscal.calib.selfcal.identify import identifiable, identify, position_errors
from tmscal.calib.selfcal.model import UR5E, jacobian, pose_from_rpy, wrench
from tmscal.calib.selfcal.study.compare import absorbed_errors, canonical
from tmscal.calib.selfcal.study.medrue import GEOMETRY_NAMES, MEDRUE

SIGMA = np.array([1 / 3] * 3 + [0.2 / 3] * 3)  # one reading, N and N·m


def _true_arm(names: list[str], seed: int) -> object:
    rng = np.random.default_rng(seed)
    p = UR5E.vector()
    for n in names:
        i = UR5E.parameter_names().index(n)
        unit = UR5E.parameter_units()[i]
        p[i] += rng.uniform(-1, 1) * (math.radians(1.0) if unit == "rad" else 2.0)
    return UR5E.with_vector(p)


def _swap(kept: list[str], pairs: dict[str, str]) -> list[str]:
    return [pairs.get(n, n) for n in kept]


def test_the_answer_does_not_depend_on_the_kept_columns():
    q = np.random.default_rng(0).uniform(-math.pi, math.pi, (80, 6))
    names = UR5E.parameter_names()
    ident = identifiable(jacobian(UR5E, q) / np.tile(SIGMA, len(q))[:, None], names)
    assert {"theta0_2", "theta0_6"} <= set(ident.kept)
    # an equally valid choice: theta0_3 for theta0_2 and the sensor's yaw for theta0_6
    other = _swap(ident.kept, {"theta0_2": "theta0_3", "theta0_6": "sensor_yaw"})
    J = jacobian(UR5E, q)
    idx = [names.index(n) for n in other]
    assert np.linalg.matrix_rank(J[:, idx]) == ident.rank
    seen = ["theta0_2", "theta0_3", "theta0_4", "theta0_5", "theta0_6", "alpha_2", "alpha_4",
            "sensor_yaw", "sensor_roll", "base_roll"]
    true = _true_arm(seen, 1)
    sigma_mean = SIGMA / 10                              # 100 readings averaged
    w = wrench(true, q) + np.random.default_rng(2).normal(size=(len(q), 6)) * sigma_mean
    fit_a = identify(UR5E, q, w, SIGMA, ident.kept)
    fit_b = identify(UR5E, q, w, SIGMA, other)
    qv = np.random.default_rng(3).uniform(-math.pi, math.pi, (300, 6))
    tcp = (0.0, 0.0, 150.0)                              # a tool: the flange turn matters
    # the kept columns decide where the fit puts the TCP
    assert position_errors(fit_a.model, fit_b.model, qv, tcp).mean() > 0.5
    can_a = canonical(UR5E, q, w, sigma_mean, start=fit_a.model)
    can_b = canonical(UR5E, q, w, sigma_mean, start=fit_b.model)
    assert np.max(np.abs(can_a.vector() - can_b.vector())) < 1e-8
    assert np.max(np.abs(position_errors(can_a, can_b, qv, tcp))) < 1e-5
    assert np.max(np.abs(absorbed_errors(true, can_a, qv, tcp)
                         - absorbed_errors(true, can_b, qv, tcp))) < 1e-5


def test_noise_free_wrenches_give_back_the_combinations_the_wrench_sees():
    q = np.random.default_rng(4).uniform(-math.pi, math.pi, (60, 6))
    # α2 = α3 = 0 exactly keeps joints 2, 3, 4 parallel and the sensor level, so that
    # θ0_2 + θ0_3 + θ0_4 and θ0_6 + sensor yaw are exactly what the wrench determines
    true = _true_arm(["theta0_2", "theta0_3", "theta0_4", "theta0_5", "theta0_6", "alpha_1",
                      "alpha_4", "alpha_5", "sensor_yaw", "base_roll", "base_pitch",
                      "cog_x", "cog_z", "a_2", "d_4"], 5)
    model = canonical(UR5E, q, wrench(true, q), SIGMA * 1e-5)
    assert np.max(np.abs(wrench(model, q) - wrench(true, q))) < 1e-6
    n = UR5E.parameter_names()
    t, e, p0 = true.vector(), model.vector(), UR5E.vector()
    for name in ("theta0_5", "alpha_1", "alpha_4", "alpha_5", "base_roll", "base_pitch"):
        assert e[n.index(name)] == pytest.approx(t[n.index(name)], abs=1e-8)
    for name in ("cog_x", "cog_z"):
        assert e[n.index(name)] == pytest.approx(t[n.index(name)], abs=1e-5)

    def total(v: np.ndarray, *names: str) -> float:
        return sum(v[n.index(k)] for k in names)

    parallel = ("theta0_2", "theta0_3", "theta0_4")
    assert total(e, *parallel) == pytest.approx(total(t, *parallel), abs=1e-8)
    assert total(e, "theta0_6", "sensor_yaw") == pytest.approx(
        total(t, "theta0_6", "sensor_yaw"), abs=1e-8)
    # what the wrench cannot split, the equal priors share out equally; lengths stay nominal
    d = e - p0
    assert d[n.index("theta0_2")] == pytest.approx(d[n.index("theta0_3")], abs=1e-8)
    assert d[n.index("theta0_3")] == pytest.approx(d[n.index("theta0_4")], abs=1e-8)
    assert d[n.index("theta0_6")] == pytest.approx(d[n.index("sensor_yaw")], abs=1e-8)
    assert d[n.index("a_2")] == 0.0 and d[n.index("d_4")] == 0.0


def test_the_hand_eye_absorbs_rigid_errors_and_not_a_shape():
    q = np.random.default_rng(6).uniform(-math.pi, math.pi, (200, 6))
    tcp = (10.0, -5.0, 120.0)
    moved = UR5E.with_vector(UR5E.vector())
    shift = pose_from_rpy((0.01, -0.02, 0.3), (5.0, -3.0, 8.0))
    moved = type(UR5E).from_dict({**UR5E.to_dict(), "base": (shift @ UR5E.base).tolist()})
    assert position_errors(UR5E, moved, q, tcp).mean() > 5.0
    assert absorbed_errors(UR5E, moved, q, tcp).max() < 1e-6
    bent = _true_arm(["a_2"], 7)                         # the upper arm's length
    delta = abs(bent.vector()[UR5E.parameter_names().index("a_2")]
                - UR5E.vector()[UR5E.parameter_names().index("a_2")])
    assert absorbed_errors(UR5E, bent, q, tcp).mean() > 0.1 * delta


# --- MedRUE ---------------------------------------------------------------------------------

def _g(name: str) -> float:
    return float(MEDRUE.geometry[GEOMETRY_NAMES.index(name)])


def _loop_closure(i: int, qa: float, qc: float) -> np.ndarray:
    """E of five-bar i by solving B + L2 (cos s, sin s) = D + L4 (cos t, sin t) numerically
    for the passive angles (s, t), from the guess that the links hang below their joints."""
    a, c = (2, 3) if i == 1 else (4, 5)
    A = np.array([_g(f"A{i}y"), _g(f"A{i}z")])
    C = np.array([_g(f"C{i}y"), _g(f"C{i}z")])
    L1, L2, L3, L4 = (_g(f"L{i}{j}") for j in (1, 2, 3, 4))
    B = A + L1 * np.array([math.cos(qa + _g(f"q{a}_0")), math.sin(qa + _g(f"q{a}_0"))])
    D = C + L3 * np.array([math.cos(qc + _g(f"q{c}_0")), math.sin(qc + _g(f"q{c}_0"))])

    def gap(st: np.ndarray) -> np.ndarray:
        s, t = st
        return B + L2 * np.array([math.cos(s), math.sin(s)]) \
            - D - L4 * np.array([math.cos(t), math.sin(t)])

    s, t = fsolve(gap, [math.radians(-60), math.radians(-120)], xtol=1e-13)
    assert np.max(np.abs(gap(np.array([s, t])))) < 1e-9
    return B + L2 * np.array([math.cos(s), math.sin(s)])


def test_medrue_forward_kinematics_against_a_numeric_loop_closure():
    q = MEDRUE.candidate_pool(25, 8)
    T = MEDRUE.forward(q)
    for k in range(len(q)):
        G = [np.array([q[k, 0] + _g("d1") + _g(f"d4{i}"), *_loop_closure(i, q[k, 2 * i - 1],
                                                                          q[k, 2 * i])])
             for i in (1, 2)]
        x6 = (G[1] - G[0]) / np.linalg.norm(G[1] - G[0])
        E1 = G[0][1:]
        D1 = np.array([_g("C1y"), _g("C1z")]) + _g("L13") * np.array(
            [math.cos(q[k, 2] + _g("q3_0")), math.sin(q[k, 2] + _g("q3_0"))])
        phi14 = math.atan2(E1[1] - D1[1], E1[0] - D1[0])
        align, _ = Rotation.align_vectors([x6], [[1.0, 0.0, 0.0]])
        R = align.as_matrix() @ Rotation.from_euler(
            "x", phi14 + q[k, 5] + _g("q6_0")).as_matrix()
        origin = 0.5 * (G[0] + G[1]) + _g("d6") * R[:, 2]
        assert np.allclose(T[k, :3, :3], R, atol=1e-9)
        assert np.allclose(T[k, :3, 3], origin, atol=1e-7)


def test_medrue_home_pose_and_what_its_wrench_sees():
    T = MEDRUE.forward(np.zeros(6))
    assert np.allclose(T[:3, 0], [1, 0, 0], atol=1e-12)   # x6 along the guide
    assert np.allclose(T[:3, 2], [0, 0, -1], atol=1e-12)  # z6 toward the patient
    q = MEDRUE.candidate_pool(400, 9)
    assert MEDRUE.reachable(q).all()
    ident = identifiable(MEDRUE.jacobian(q) / np.tile(SIGMA, len(q))[:, None],
                         MEDRUE.parameter_names())
    zero = {n for n, r in ident.removed if r.startswith("zero")}
    # the guide offset and the probe length translate the probe: no wrench sees them
    assert {"d1", "d6", "base_x", "base_yaw", "sensor_z"} <= zero
    # the planes' offsets matter only through their difference
    assert ("d41" in ident.kept) != ("d42" in ident.kept)
    # unlike a serial arm's, the five-bars' link lengths turn the probe: identifiable
    lengths = [n for n in ident.kept if n.startswith("L")]
    assert len(lengths) >= 6
    assert 25 <= len(ident.kept) <= 35
