"""One rule for which matrices leave tmscal (issue 24, item 2; docs/exports.md, "Which matrices
leave tmscal"): the calibration file's X, Y, Z, the loader, every export format and the
OpenIGTLink stream, received by pyigtl's client as 3D Slicer connects, carry the same
orthonormal (rigid) Z — for a QR36 calibration that applies its raw matrices and for an ``ml``
calibration that found a tracker distortion. The files are written by ``tmscal solve -o`` and
``tmscal export``; the stream is ``tmscal.stream.StreamServer`` sending
``frame_transforms`` of a tracker frame, on a loopback port of its own."""

from __future__ import annotations

import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tests.rigs import unique_host, wait_until
from tmscal.cli import main
from tmscal.drivers.base import ToolState, TrackerFrame
from tmscal.exports import load_calibration
from tmscal.geometry import matrix_from_quaternion
from tmscal.stream import StreamServer, frame_transforms
from tmscal.timing import Deadline

pyigtl = pytest.importorskip("pyigtl")

F32_MM = 5e-3  # OpenIGTLink carries float32: translations up to ~2,000 mm
F32_ROT = 1e-6  # rotation entries in float32
LPS = np.diag([-1.0, -1.0, 1.0, 1.0])


def _run(*args: object) -> None:
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 0, r.output


@pytest.fixture(scope="module")
def calibs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """qr36 (raw matrices applied, the default) and ml with a tracker distortion."""
    d = tmp_path_factory.mktemp("matrix-rule")
    _run("simulate", "-o", d / "s.jsonl", "--poses", 60, "--seed", 7)
    _run("simulate", "-o", d / "d.jsonl", "--poses", 60, "--seed", 8, "--tracker-scale",
         "1.002,0.999,1")
    _run("solve", d / "s.jsonl", "-o", d / "qr36.yaml", "--folds", 2)
    _run("solve", d / "d.jsonl", "-o", d / "ml.yaml", "--method", "ml", "--option",
         "distortion=axis", "--folds", 2)
    return {"qr36": d / "qr36.yaml", "ml": d / "ml.yaml"}


def _export(calib: Path, fmt: str, name: str) -> Path:
    out = calib.with_name(f"{calib.stem}-{name}")
    _run("export", calib, "--format", fmt, "-o", out, "--force")
    return out


def _itk_Z(path: Path) -> np.ndarray:
    """Z from the .tfm as Slicer reads it: to-parent = (C T C)⁻¹ (docs/exports.md)."""
    line = next(ln for ln in path.read_text().splitlines() if ln.startswith("Parameters:"))
    p = [float(v) for v in line.split()[1:]]
    T = np.eye(4)
    T[:3, :3] = np.reshape(p[:9], (3, 3))
    T[:3, 3] = p[9:]
    return np.linalg.inv(LPS @ T @ LPS)


def _plus_Z(path: Path) -> np.ndarray:
    root = ET.parse(path).getroot()
    t = next(e for e in root.iter("Transform")
             if (e.get("From"), e.get("To")) == ("Tracker", "RobotBase"))
    return np.array([float(v) for v in t.get("Matrix", "").split()]).reshape(4, 4)


def _handeye_Z(path: Path) -> np.ndarray:
    t = yaml.safe_load(path.read_text())["transformation"]
    Z = np.eye(4)
    Z[:3, :3] = matrix_from_quaternion([t["qw"], t["qx"], t["qy"], t["qz"]])
    Z[:3, 3] = np.array([t["x"], t["y"], t["z"]]) * 1000.0
    return Z


def _invesalius_Z(path: Path) -> np.ndarray:
    nums = [float(v) for v in path.read_text().split()]
    _, Y, affine = np.split(np.array(nums).reshape(12, 4), 3)
    np.testing.assert_array_equal(Y, affine)
    return Y


def _streamed(cal: object, C: np.ndarray, B: np.ndarray, coil_from: str = "marker"
              ) -> dict[str, np.ndarray]:
    """What a pyigtl client receives for one tracker frame with the marker at B and the
    probe at C (tracker ← tool, mm), the coil from ``coil_from``."""
    frame = TrackerFrame(1, 0.0, {"marker": ToolState(B), "probe": ToolState(C)})
    sent = frame_transforms(frame, cal, coil_from=coil_from)  # type: ignore[arg-type]
    host = unique_host()
    with StreamServer(host, 0) as srv:
        client = pyigtl.OpenIGTLinkClient(host=host, port=srv.port)
        try:
            wait_until(lambda: len(srv.peers) == 1, 30.0, "the pyigtl client connected")
            got: dict[str, np.ndarray] = {}
            guard = Deadline(30.0)
            while len(got) < len(sent):
                assert not guard.expired(), f"received only {sorted(got)}"
                srv.send_transforms(sent, 1.0)
                time.sleep(0.01)
                for m in client.get_latest_messages():
                    got[m.device_name] = np.asarray(m.matrix, dtype=float)
        finally:
            client.stop()
    return got


def _rigid(M: np.ndarray) -> bool:
    R = M[:3, :3]
    return bool(np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) > 0)


@pytest.mark.parametrize("name", ["qr36", "ml"])
def test_file_loader_exports_and_stream_carry_the_same_rigid_z(calibs, name):
    path = calibs[name]
    doc = yaml.safe_load(path.read_text())
    Z = np.asarray(doc["Z"], dtype=float)
    assert _rigid(Z)
    # the raw Z differs from it (raw applied, or the distortion's G): exporting it would show
    assert not np.allclose(np.asarray(doc["raw"]["Z"], dtype=float), Z, atol=1e-6)
    cal = load_calibration(path)
    np.testing.assert_array_equal(cal.Z, Z)
    np.testing.assert_array_equal(cal.exported()["Z"], Z)
    np.testing.assert_allclose(_itk_Z(_export(path, "itk", "Z.tfm")), Z, atol=1e-9)
    np.testing.assert_allclose(_plus_Z(_export(path, "plus", "plus.xml")), Z, atol=1e-12)
    np.testing.assert_allclose(_handeye_Z(_export(path, "easy-handeye", "eh.yaml")), Z,
                               atol=1e-9)
    np.testing.assert_allclose(_invesalius_Z(_export(path, "invesalius", "r.rbtf")), Z,
                               atol=1e-12)
    j = yaml.safe_load(_export(path, "json", "c.json").read_text())
    np.testing.assert_array_equal(np.asarray(j["Z"], dtype=float), Z)

    C = np.linalg.inv(Z)  # the probe near the robot base's origin, and the marker beside it
    C[:3, 3] += [20.0, -10.0, 5.0]
    B = C.copy()
    B[:3, 3] += [0.0, 30.0, 0.0]
    coil = B @ np.linalg.inv(np.asarray(doc["X"], dtype=float)) @ np.asarray(doc["Y"],
                                                                              dtype=float)
    for coil_from, expected in (("marker", coil), ("probe", C)):
        got = _streamed(cal, C, B, coil_from)
        assert set(got) == {"TrackerToRobotBase", "CoilToTracker", "ProbeToTracker",
                            "MarkerToTracker", "CoilToRobotBase"}
        sent = got["TrackerToRobotBase"]
        np.testing.assert_allclose(sent[:3, 3], Z[:3, 3], atol=F32_MM)
        np.testing.assert_allclose(sent[:3, :3], Z[:3, :3], atol=F32_ROT)
        # the coil from the exported (rigid) X and Y, through the same Z (with a
        # distortion, the pose is undistorted first)
        np.testing.assert_allclose(got["CoilToTracker"][:3, 3], expected[:3, 3], atol=F32_MM)
        if not cal.distortion:
            np.testing.assert_allclose(got["CoilToRobotBase"][:3, 3], (Z @ expected)[:3, 3],
                                       atol=F32_MM)


def test_solve_prints_the_z_the_file_and_exports_carry_and_says_so(calibs, tmp_path):
    session = calibs["qr36"].with_name("s.jsonl")
    r = CliRunner().invoke(main, ["solve", str(session), "-o", str(tmp_path / "c.yaml"),
                                  "--folds", "2"])
    assert r.exit_code == 0, r.output
    text = " ".join(r.output.split())
    assert "raw matrices applied" in text
    assert ("the matrices below are the orthonormal X, Y, Z (rotations projected to SO(3), "
            "translations re-solved): the ones the calibration file's X, Y, Z, every export "
            "and tmscal stream carry") in text
    lines = r.output.splitlines()
    at = lines.index("  Z = base_from_tracker (orthonormal, mm)")
    printed = np.array([[float(v) for v in ln.split()] for ln in lines[at + 1:at + 5]])
    Z = np.asarray(yaml.safe_load((tmp_path / "c.yaml").read_text())["Z"], dtype=float)
    np.testing.assert_allclose(printed, Z, atol=1e-5)
    raw = np.asarray(yaml.safe_load((tmp_path / "c.yaml").read_text())["raw"]["Z"])
    assert np.abs(printed[:3, :3] - raw[:3, :3]).max() > 1e-5  # not the raw one printed
