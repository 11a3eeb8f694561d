"""The sim rig's tracker distortion (tmscal.sim.Noise tracker_scale / tracker_shear): tracked
positions are D p about the tracker origin; raw QR36 absorbs an isotropic scale, a rigid
calibration cannot."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from tmscal.calib import solve
from tmscal.config import construct
from tmscal.errors import ConfigError
from tmscal.geometry import make_pose
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, simulate, tms_rig_truth


def _rig(noise: Noise) -> SimRig:
    truth = tms_rig_truth()
    rig = SimRig(truth, noise=noise, rng=np.random.default_rng(0))
    rig.move_flange(TMS_RIG_P0 @ make_pose(np.eye(3), [20.0, -30.0, 10.0]))
    return rig


def test_isotropic_scale_multiplies_tracked_translations_about_the_origin() -> None:
    s = 1.001
    clean = _rig(Noise.none())
    scaled = _rig(Noise(0.0, 0.0, 0.0, tracker_scale=s))
    for body in ("marker", "probe"):
        T, D = clean.observe(body), scaled.observe(body)
        assert np.linalg.norm(T[:3, 3]) > 1000  # far from the origin: the scale shows
        np.testing.assert_allclose(D[:3, 3], s * T[:3, 3], atol=1e-6)
        np.testing.assert_allclose(D[:3, :3], T[:3, :3], atol=1e-9)


def test_per_axis_scale_and_shear_map_positions_by_D() -> None:
    noise = Noise(0.0, 0.0, 0.0, tracker_scale=[1.002, 0.999, 1.0],
                  tracker_shear=[0.001, 0.0, -0.0005])
    D = np.array([[1.002, 0.001, 0.0], [0.0, 0.999, -0.0005], [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(noise.tracker_distortion, D)
    clean, dist = _rig(Noise.none()), _rig(noise)
    T, M = clean.observe("marker"), dist.observe("marker")
    # Horn's fit of the distorted spheres: the centroid (the tool origin) lands at D t
    np.testing.assert_allclose(M[:3, 3], D @ T[:3, 3], atol=1e-6)


def test_noise_config_keys_build_the_distortion_and_bad_values_are_config_errors() -> None:
    n = construct(Noise, "rig.yaml: key 'mock.noise'", tracker_scale=[1.001, 1.001, 1.001],
                  tracker_shear=[0, 0, 0])
    assert n.tracker_scale == (1.001, 1.001, 1.001) and n.distorted
    assert not Noise().distorted
    for bad in ({"tracker_scale": [1.0, 1.0]}, {"tracker_scale": "big"},
                {"tracker_scale": 3.0}, {"tracker_shear": 0.1}):
        with pytest.raises(ConfigError, match="mock.noise.*tracker_s"):
            construct(Noise, "rig.yaml: key 'mock.noise'", **bad)


def _holdout_e_t(scale: float, seed: int) -> tuple[float, float]:
    """Held-out e_t (mm) of raw and of orthonormal QR36: train on 100 poses, test on 100."""
    noise = Noise(0.01, 0.005, 0.005, tracker_scale=scale)
    _, d = simulate(200, np.random.default_rng(seed), plan="eq14", noise=noise)
    A, B, C = d["A"], d["marker"], d["probe"]
    out = []
    for ortho in (False, True):
        cal = solve(A[:100], B[:100], C[:100], method="qr36", orthonormal=ortho)
        out.append(cal.errors(A[100:], B[100:], C[100:])["e_t_mm"])
    return out[0], out[1]


@pytest.mark.parametrize("seed", [1, 2])
def test_raw_qr36_absorbs_an_isotropic_scale_a_rigid_solution_cannot(seed: int) -> None:
    raw0, rigid0 = _holdout_e_t(1.0, seed)
    raw1, rigid1 = _holdout_e_t(1.01, seed)  # +1 %: ≈ 1 mm over the ±100 mm plan
    # without distortion raw and rigid agree (both at the noise level)
    assert rigid0 < 1.5 * raw0
    # the raw 3×4 matrices absorb the scale: the error stays at the undistorted level …
    assert raw1 < 1.3 * raw0
    # … the rigid one cannot: its held-out error grows several-fold
    assert rigid1 > 3.0 * rigid0
    assert rigid1 > 3.0 * raw1


def test_a_mock_rig_config_sets_the_distortion(mock_config) -> None:
    from tmscal.config import load_config
    from tmscal.mocks.launch import build_sim_rig

    base = "mock-ur-polaris.yaml"
    mock = yaml.safe_load((Path(__file__).parents[2] / "configs" / base).read_text())["mock"]
    mock["noise"] = {"fiducial_sigma_mm": 0.0, "robot_rot_sigma_deg": 0.0,
                     "robot_trans_sigma_mm": 0.0, "tracker_scale": [1.002, 1.0, 1.0]}
    rig = build_sim_rig(load_config(mock_config(base, mock=mock)))
    clean = SimRig(rig.truth, noise=Noise.none(), start=rig.commanded)
    T, M = clean.observe("marker"), rig.observe("marker")
    np.testing.assert_allclose(M[:3, 3], np.array([1.002, 1.0, 1.0]) * T[:3, 3], atol=1e-6)
    bad = dict(mock, noise={"tracker_scale": [1.0, 1.0]})
    with pytest.raises(ConfigError, match="mock.noise.*tracker_scale"):
        build_sim_rig(load_config(mock_config(base, mock=bad)))
