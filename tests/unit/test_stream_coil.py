"""The coil from the marker (docs/streaming.md, "Where the coil comes from"): the
calibration's marker ← coil (``Calibration.marker_from_coil``), the placement rule on marker
poses (``Calibration.placement(body="marker")``, with a tracker distortion), which body a
stream takes the coil from (``tmscal.stream.coil_source``), the probe's cross-check
(``coil_difference``, ``CrossCheck``) and what ``tmscal stream`` says about it. Hand-made
frames and calibrations of the built-in TMS rig's truth; 4×4 poses in mm."""

from __future__ import annotations

import io

import numpy as np
import pytest

from tmscal.calib import Calibration
from tmscal.drivers.base import ToolState, TrackerFrame
from tmscal.errors import CalibrationError
from tmscal.geometry import make_pose, rot_x, rot_z
from tmscal.sim import tms_rig_truth
from tmscal.stream import CrossCheck, StreamStats, coil_difference, coil_source, frame_transforms

TRUTH = tms_rig_truth()


def _cal(Y: np.ndarray | None = TRUTH.Y, **kw) -> Calibration:
    return Calibration("qr36", 10, X=TRUTH.X, Z=TRUTH.Z, X_raw=TRUTH.X, Z_raw=TRUTH.Z, Y=Y,
                       Y_raw=Y, **kw)


def _rig_poses(t_mm=(520.0, 30.0, 380.0)) -> tuple[np.ndarray, np.ndarray]:
    """(B, C) of the truth with the flange at t_mm (rotated about x by 170°)."""
    A = make_pose(rot_x(np.radians(170.0)), t_mm)
    Zi = np.linalg.inv(TRUTH.Z)
    return Zi @ A @ TRUTH.X, Zi @ A @ TRUTH.Y


def test_marker_from_coil_is_x_inverse_y_and_rigid():
    M = _cal().marker_from_coil()
    np.testing.assert_allclose(M, np.linalg.solve(TRUTH.X, TRUTH.Y), atol=1e-12)
    np.testing.assert_allclose(M[:3, :3] @ M[:3, :3].T, np.eye(3), atol=1e-12)
    B, C = _rig_poses()
    np.testing.assert_allclose(B @ M, C, atol=1e-9)  # the marker alone gives the coil
    with pytest.raises(CalibrationError, match="marker-only calibration has no coil"):
        _cal(Y=None).marker_from_coil()


def test_marker_from_coil_uses_the_exported_matrices_not_the_raw_ones():
    """A calibration that applies its raw (non-orthogonal) matrices: marker ← coil is still
    X⁻¹ · Y of the orthonormal X and Y that every export carries."""
    raw_X = TRUTH.X.copy()
    raw_X[:3, :3] *= 1.01
    cal = Calibration("qr36", 10, X=TRUTH.X, Z=TRUTH.Z, X_raw=raw_X, Z_raw=TRUTH.Z,
                      Y=TRUTH.Y, Y_raw=TRUTH.Y)
    np.testing.assert_allclose(cal.marker_from_coil(), np.linalg.solve(TRUTH.X, TRUTH.Y),
                               atol=1e-12)


def test_placement_on_the_marker_is_the_coil_on_the_undistorted_marker():
    """body='marker': the targets are B' · X⁻¹ · Y with B' the marker undistorted; without a
    distortion they are the probe poses themselves, so the flange command is the same as
    from the probe."""
    B, C = _rig_poses()
    cal = _cal()
    targets, _, _ = cal.placement(B[None], body="marker")
    np.testing.assert_allclose(targets[0], C, atol=1e-9)
    np.testing.assert_allclose(cal.flange_command(B[None], body="marker"),
                               cal.flange_command(C[None]), atol=1e-9)
    D = 1.001 * np.eye(3)
    scaled = _cal(distortion={"model": "scale", "matrix": D.tolist()})
    Bm = B.copy()
    Bm[:3, 3] = D @ B[:3, 3]  # the tracker reports positions D · t (an isotropic scale)
    targets, _, _ = scaled.placement(Bm[None], body="marker")
    np.testing.assert_allclose(targets[0], C, atol=1e-9)
    # undistorting the measured coil pose instead would scale the marker → coil offset too
    wrong, _, _ = scaled.placement((Bm @ scaled.marker_from_coil())[None])
    assert np.linalg.norm(wrong[0][:3, 3] - C[:3, 3]) > 1e-3
    with pytest.raises(ValueError, match="body"):
        cal.placement(B[None], body="flange")


def test_coil_source_one_rule_per_stream():
    cal, marker_only = _cal(), _cal(Y=None)
    assert coil_source(["marker", "probe"], cal) == "marker"
    assert coil_source(["marker"], cal) == "marker"
    assert coil_source(["probe"], cal) == "probe"
    assert coil_source(["marker", "probe"], marker_only) == "probe"
    assert coil_source(["marker"], marker_only) is None
    assert coil_source(["coil", "ref"], cal, marker="coil") == "marker"


def test_frame_transforms_with_a_marker_only_calibration():
    B, C = _rig_poses()
    fr = TrackerFrame(1, 0.0, {"marker": ToolState(B), "probe": ToolState(C)})
    with pytest.raises(CalibrationError, match="marker-only"):
        frame_transforms(fr, _cal(Y=None))
    got = frame_transforms(fr, _cal(Y=None), coil_from=None)
    assert set(got) == {"ProbeToTracker", "MarkerToTracker", "TrackerToRobotBase"}
    with pytest.raises(ValueError, match="coil_from"):
        frame_transforms(fr, _cal(), coil_from="flange")


def test_coil_difference_and_the_cross_check():
    B, C = _rig_poses()
    T = make_pose(rot_z(np.radians(1.5)), [0.0, 0.0, 2.0])
    mm, deg = coil_difference(C, C @ T)
    assert mm == pytest.approx(2.0, abs=1e-9) and deg == pytest.approx(1.5, abs=1e-9)
    assert coil_difference(C, C) == pytest.approx((0.0, 0.0), abs=1e-6)
    cc = CrossCheck()
    assert cc.mean_mm is None and cc.last is None
    for v in ((0.1, 0.2), (0.3, 0.1), (0.2, 0.6)):
        cc.add(*v)
    assert cc.n == 3 and cc.last == (0.2, 0.6)
    assert cc.mean_mm == pytest.approx(0.2) and cc.mean_deg == pytest.approx(0.3)
    assert (cc.max_mm, cc.max_deg) == (0.3, 0.6)


def test_the_cli_says_where_the_coil_comes_from_and_shows_the_cross_check():
    from tmscal.cli.stream import _coil_note, _crosscheck_line, _Status

    note = _coil_note("marker", ["marker", "probe"], True)
    assert note.startswith("coil:") and "from the marker" in note and "ProbeToTracker" in note
    note = _coil_note("marker", ["marker"], True)
    assert note.startswith("coil:") and "ProbeToTracker" not in note
    note = _coil_note("probe", ["marker", "probe"], False)
    assert note.startswith("warning:") and "marker-only" in note and "probe only" in note
    note = _coil_note("probe", ["probe"], True)
    assert note.startswith("warning:") and "no 'marker' tool" in note
    note = _coil_note(None, ["marker"], False)
    assert note.startswith("warning:") and "not sent" in note

    st = StreamStats(frames=10, sent=10, coil_from="marker")
    assert _crosscheck_line(st) is None
    status = _Status(io.StringIO(), ["marker", "probe"])
    status.width = 200
    assert "probe vs marker" not in status.text(st)
    st.crosscheck.add(0.125, 0.0625)
    st.crosscheck.add(0.375, 0.1875)
    assert "probe vs marker coil 0.38 mm 0.19°" in status.text(st)
    assert _crosscheck_line(st) == ("cross-check, probe vs marker-derived coil over 2 frames: "
                                    "mean 0.250 mm 0.125°, max 0.375 mm 0.188°")
