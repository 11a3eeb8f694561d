"""Each export read back the way its consumer reads it (SimpleITK for the ITK file, an XML
parser against PLUS' element and attribute names, YAML as easy_handeye loads it, InVesalius'
CSV reader and tms-robot-control's split) and checked numerically against the calibration."""

from __future__ import annotations

import csv
import datetime as dt
import json
import os
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.exports import load_calibration
from tmscal.session import read_session

sitk = pytest.importorskip("SimpleITK", reason="SimpleITK (the test extra) reads the .tfm")

C_LPS = np.diag([-1.0, -1.0, 1.0])


def run(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    return r


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("exports")
    run("simulate", "-o", d / "s.jsonl", "--poses", 60, "--seed", 7)
    run("simulate", "-o", d / "d.jsonl", "--poses", 60, "--seed", 8, "--tracker-scale",
        "1.002,0.999,1")
    run("solve", d / "s.jsonl", "-o", d / "qr36.yaml", "--folds", 2)
    run("solve", d / "d.jsonl", "-o", d / "ml.yaml", "--method", "ml", "--option",
        "distortion=axis", "--folds", 2)
    return d


def export(files, calib, fmt, out, *extra):
    run("export", files / calib, "--format", fmt, "-o", files / out, "--force", *extra)
    return files / out


def _tracker_points(n=20, seed=0):
    rng = np.random.default_rng(seed)  # points in the tracker's working volume, mm
    return rng.uniform([-300, -300, -2400], [300, 300, -900], size=(n, 3))


@pytest.mark.parametrize("calib", ["qr36.yaml", "ml.yaml"])
def test_itk_file_read_by_simpleitk_maps_as_documented(files, calib):
    cal = load_calibration(files / calib)
    Z = cal.Z  # base ← tracker, the orthonormal one (docs/exports.md: what leaves is rigid)
    T = sitk.ReadTransform(str(export(files, calib, "itk", "Z.tfm")))
    assert T.GetName() == "AffineTransform"
    # ITK applies the resampling direction in LPS: a base point (RAS numbers b, LPS C b)
    # goes to the LPS coordinates of the tracker point it came from
    for q in _tracker_points():
        b = Z[:3, :3] @ q + Z[:3, 3]
        np.testing.assert_allclose(T.TransformPoint((C_LPS @ b).tolist()), C_LPS @ q,
                                   atol=1e-7)
    # what Slicer makes of it: RAS (conjugate by C), then from-parent → to-parent (invert)
    A = sitk.AffineTransform(T)
    M = np.eye(4)
    M[:3, :3] = np.array(A.GetMatrix()).reshape(3, 3)
    M[:3, 3] = A.GetTranslation()
    assert np.allclose(A.GetCenter(), 0)
    C4 = np.diag([-1.0, -1.0, 1.0, 1.0])
    np.testing.assert_allclose(np.linalg.inv(C4 @ M @ C4), Z, atol=1e-9)
    # rigid, also for the calibration that found a tracker distortion
    np.testing.assert_allclose(M[:3, :3] @ M[:3, :3].T, np.eye(3), atol=1e-12)
    text = (files / "Z.tfm").read_text()
    assert text.startswith("#Insight Transform File V1.0\n")
    assert "base_from_tracker" in text and "mm" in text


def _plus_edges(root: ET.Element) -> list[tuple[str, str, np.ndarray | None]]:
    """The transforms PLUS' transform repository holds for a device set, in the order it sets
    them: each CoordinateDefinitions Transform (From, To, its Matrix read row by row), then
    each tracked tool's ``<Id>To<ToolReferenceFrame>`` (None: its pose comes per frame)."""
    edges: list[tuple[str, str, np.ndarray | None]] = []
    for t in root.iter("Transform"):
        vals = [float(v) for v in t.get("Matrix", "").split()]
        assert len(vals) == 16
        edges.append((t.get("From"), t.get("To"), np.reshape(vals, (4, 4))))
    for dev in root.iter("Device"):
        ref = dev.get("ToolReferenceFrame")
        for src in dev.findall("./DataSources/DataSource"):
            if src.get("Type") == "Tool":
                edges.append((src.get("Id"), ref, None))
    return edges


def _plus_loop(edges) -> str | None:
    """The first transform PLUS' repository refuses because a path between its two frames
    already exists (vtkPlusTransformRepository::SetTransform: "A transform path already
    exists between …"), as "FromToTo"; None when it accepts every one (the frames form a
    tree)."""
    group: dict[str, str] = {}

    def root_of(f: str) -> str:
        while group.setdefault(f, f) != f:
            f = group[f]
        return f

    for a, b, _ in edges:
        ra, rb = root_of(a), root_of(b)
        if ra == rb:
            return f"{a}To{b}"
        group[ra] = rb
    return None


def _plus_chain(edges, frm: str, to: str, tools: dict[str, np.ndarray]) -> np.ndarray:
    """``frm`` → ``to`` (4×4) composed along the repository's path, as PLUS computes it: a
    definition's matrix or a tool's pose (``tools``: Id → pose; a tool not given is not
    seen), or its inverse when walked backwards."""
    step: dict[str, list[tuple[str, np.ndarray]]] = {}
    for a, b, M in edges:
        T = tools.get(a) if M is None else M
        if T is None:
            continue
        step.setdefault(a, []).append((b, T))
        step.setdefault(b, []).append((a, np.linalg.inv(T)))
    todo, seen = [(frm, np.eye(4))], {frm}
    while todo:
        f, T = todo.pop()
        if f == to:
            return T
        for g, S in step.get(f, []):
            if g not in seen:
                seen.add(g)
                todo.append((g, S @ T))  # g ← f ← frm
    raise AssertionError(f"no path from {frm} to {to}")


def test_the_plus_loop_check_finds_a_loop():
    """The checker itself: the layout the export wrote before (the probe tool named
    CoilCentre beside a CoilCentreToFlange definition) closes a loop PLUS refuses."""
    I4 = np.eye(4)
    old = [("CoilMarker", "Flange", I4), ("CoilCentre", "Flange", I4),
           ("Tracker", "RobotBase", I4), ("CoilMarker", "Tracker", None),
           ("CoilCentre", "Tracker", None)]
    assert _plus_loop(old) == "CoilCentreToTracker"
    assert _plus_loop(old[:4]) is None


def test_plus_device_set_parses_against_plus_names(files, tmp_path):
    cal = load_calibration(files / "qr36.yaml")
    doc = yaml.safe_load((files / "qr36.yaml").read_text())
    root = ET.parse(export(files, "qr36.yaml", "plus", "plus.xml")).getroot()
    assert root.tag == "PlusConfiguration"
    tr = {(t.get("From"), t.get("To")): t for t in root.iter("Transform")}
    assert set(tr) == {("CoilMarker", "Flange"), ("CoilCentre", "CoilMarker"),
                       ("Tracker", "RobotBase")}
    X, Y = np.asarray(doc["X"], dtype=float), np.asarray(doc["Y"], dtype=float)
    for (a, b), M, err in (
            (("CoilMarker", "Flange"), cal.X, doc["errors"]["marker"]["trans_mm"]),
            (("CoilCentre", "CoilMarker"), np.linalg.inv(X) @ Y, None),
            (("Tracker", "RobotBase"), cal.Z, doc["errors"]["e_t_mm"])):
        vals = [float(v) for v in tr[a, b].get("Matrix").split()]
        assert len(vals) == 16
        np.testing.assert_allclose(np.reshape(vals, (4, 4)), M, rtol=0, atol=1e-12)
        if err is None:  # no hold-out error is defined for marker ← coil by itself
            assert tr[a, b].get("Error") is None
        else:
            assert float(tr[a, b].get("Error")) == pytest.approx(err, abs=5e-5)
        dt.datetime.strptime(tr[a, b].get("Date"), "%Y.%m.%d %H:%M:%S")
    dev = root.find("./DataCollection/Device")
    assert dev.get("Type") == "NDITracker" and dev.get("ToolReferenceFrame") == "Tracker"
    ids = {s.get("Id"): s.get("RomFile") for s in dev.findall("./DataSources/DataSource")
           if s.get("Type") == "Tool"}
    assert set(ids) == {"CoilMarker", "Probe"}
    # with the rig config recorded (a session acquired at a rig), the ROM files and port
    doc["provenance"]["config"] = {"tracker": {
        "driver": "ndi", "port": "/dev/ttyUSB0", "baud": 115200, "frame_rate_hz": 60,
        "tools": {"marker": "/lab/roms/marker.rom", "probe": "/lab/roms/probe.rom"}}}
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(doc))
    run("export", tmp_path / "rig.yaml", "--format", "plus", "-o", tmp_path / "p.xml")
    dev = ET.parse(tmp_path / "p.xml").getroot().find("./DataCollection/Device")
    roms = {s.get("Id"): s.get("RomFile") for s in dev.findall("./DataSources/DataSource")}
    assert roms == {"CoilMarker": "/lab/roms/marker.rom", "Probe": "/lab/roms/probe.rom"}
    assert (dev.get("SerialPort"), dev.get("BaudRate")) == ("/dev/ttyUSB0", "115200")
    assert [s.get("Id") for s in dev.findall("./OutputChannels/OutputChannel/DataSource")] \
        == ["CoilMarker", "Probe"]


def test_plus_repository_gives_the_coil_from_the_marker_alone(files):
    """PLUS' transform repository on the exported device set: every transform is accepted
    (no loop), and the coil in the tracker, chained from the tracked CoilMarker alone, is
    B · X⁻¹ · Y; through CoilMarker the coil in the flange is Y and the coil in the robot base
    Z · B · X⁻¹ · Y. X, Y, Z read from the calibration file with PyYAML."""
    doc = yaml.safe_load((files / "qr36.yaml").read_text())
    X, Y, Z = (np.asarray(doc[k], dtype=float) for k in ("X", "Y", "Z"))
    edges = _plus_edges(ET.parse(export(files, "qr36.yaml", "plus", "plus.xml")).getroot())
    assert _plus_loop(edges) is None
    A, B, C, _ = read_session(files / "s.jsonl").arrays()
    for i in (0, 17, 42):
        tools = {"CoilMarker": B[i], "Probe": C[i]}
        coil = _plus_chain(edges, "CoilCentre", "Tracker", tools)
        np.testing.assert_allclose(coil, B[i] @ np.linalg.inv(X) @ Y, rtol=0, atol=1e-9)
        np.testing.assert_allclose(_plus_chain(edges, "CoilCentre", "RobotBase", tools),
                                   Z @ B[i] @ np.linalg.inv(X) @ Y, rtol=0, atol=1e-9)
        # the probe as tracked, a cross-check: within the simulated noise of the coil
        probe = _plus_chain(edges, "Probe", "Tracker", tools)
        assert np.linalg.norm(probe[:3, 3] - coil[:3, 3]) < 1.0
    np.testing.assert_allclose(_plus_chain(edges, "CoilCentre", "Flange", {}), Y, rtol=0,
                               atol=1e-9)


def test_plus_device_set_of_a_marker_only_calibration_has_no_coil(files, tmp_path):
    """A marker-only calibration (no Y): no coil definition and no probe tool."""
    doc = yaml.safe_load((files / "qr36.yaml").read_text())
    for d in (doc, doc["raw"]):
        d.pop("Y")
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    run("export", tmp_path / "m.yaml", "--format", "plus", "-o", tmp_path / "m.xml")
    root = ET.parse(tmp_path / "m.xml").getroot()
    assert {(t.get("From"), t.get("To")) for t in root.iter("Transform")} == {
        ("CoilMarker", "Flange"), ("Tracker", "RobotBase")}
    assert [s.get("Id") for s in root.iter("DataSource") if s.get("Type") == "Tool"] == [
        "CoilMarker"]


def test_plus_device_set_of_another_tracker_has_no_rom_files(files, tmp_path, monkeypatch):
    """A session on a tracker driver that is not an NDI: no RomFile, and the file and the
    command say why (the ROM files come from the NDI driver's settings only)."""
    from tmscal import registry

    monkeypatch.setitem(registry.SPECS, "lab", registry.DriverSpec(
        "lab", "tracker", "tmscal.drivers.ndi.tracker:NDITracker"))
    doc = yaml.safe_load((files / "qr36.yaml").read_text())
    doc["provenance"]["config"] = {"tracker": {
        "driver": "lab", "frame_rate_hz": 60, "tools": {"marker": "M1", "probe": "P1"}}}
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(doc))
    r = run("export", tmp_path / "rig.yaml", "--format", "plus", "-o", tmp_path / "p.xml")
    assert "not an NDI" in r.output
    text = (tmp_path / "p.xml").read_text()
    assert "driver 'lab') is not an NDI and has no ROM files" in text
    dev = ET.parse(tmp_path / "p.xml").getroot().find("./DataCollection/Device")
    assert dev.get("Type").startswith("CHECK") and dev.get("SerialPort") is None
    sources = dev.findall("./DataSources/DataSource")
    assert [s.get("Id") for s in sources] == ["CoilMarker", "Probe"]
    assert all(s.get("RomFile") is None for s in sources)


def _R_from_xyzw(x, y, z, w):
    """Rotation matrix of a unit quaternion (Hamilton, scalar w), written out."""
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


#: the arguments of easy_handeye's HandeyeCalibrationParameters (ROS 1) and the fields of
#: easy_handeye2_msgs/HandeyeCalibrationParameters (ROS 2)
EH1_PARAMS = {"namespace", "move_group_namespace", "move_group", "eye_on_hand",
              "robot_base_frame", "robot_effector_frame", "tracking_base_frame",
              "tracking_marker_frame"}
EH2_PARAMS = {"name", "calibration_type", "robot_base_frame", "robot_effector_frame",
              "tracking_base_frame", "tracking_marker_frame", "freehand_robot_movement",
              "move_group_namespace", "move_group"}


@pytest.mark.parametrize("version", [1, 2])
def test_easy_handeye_yaml_is_z_in_metres_xyzw(files, version):
    cal = load_calibration(files / "qr36.yaml")
    extra = ["--easy-handeye2"] if version == 2 else []
    d = yaml.safe_load(export(files, "qr36.yaml", "easy-handeye", f"eh{version}.yaml",
                              "--frame", "robot_base_frame=denso_base", *extra).read_text())
    if version == 1:
        assert set(d) == {"parameters", "transformation"}
        assert set(d["parameters"]) == EH1_PARAMS and d["parameters"]["eye_on_hand"] is False
        t = d["transformation"]
        xyz, q = [t["x"], t["y"], t["z"]], [t["qx"], t["qy"], t["qz"], t["qw"]]
    else:
        assert set(d) == {"parameters", "transform"}
        assert set(d["parameters"]) == EH2_PARAMS
        assert d["parameters"]["calibration_type"] == "eye_on_base"
        t = d["transform"]
        xyz = [t["translation"][k] for k in "xyz"]
        q = [t["rotation"][k] for k in "xyzw"]
    assert d["parameters"]["robot_base_frame"] == "denso_base"
    np.testing.assert_allclose(np.array(xyz) * 1000.0, cal.Z[:3, 3], atol=1e-9)
    assert np.linalg.norm(q) == pytest.approx(1.0) and q[3] >= 0
    np.testing.assert_allclose(_R_from_xyzw(*q), cal.Z[:3, :3], atol=1e-12)


def test_invesalius_rbtf_read_as_invesalius_and_tms_robot_control_do(files):
    cal = load_calibration(files / "qr36.yaml")
    path = export(files, "qr36.yaml", "invesalius", "robot.rbtf")
    # InVesalius' RobotCoregistrationDialog.LoadRegistration
    with open(path) as f:
        content = list(csv.reader(f, delimiter="\t"))
    data = np.vstack(list(np.float64(content))).tolist()
    # tms-robot-control's OnSetRobotTransformationMatrix
    X, Y, affine = np.split(np.array(data).reshape(12, 4), 3, axis=0)
    np.testing.assert_allclose(X, cal.X, atol=0)
    np.testing.assert_allclose(Y, cal.Z, atol=0)
    np.testing.assert_allclose(affine, cal.Z, atol=0)
    # its transformation_tracker_to_robot on the session's marker poses: rotation of
    # Y N X⁻¹ and position of affine · N are the flange's rotation and the point t(X) of
    # the flange (the TCP offset it needs), within the simulated noise
    A, B, _, _ = read_session(files / "s.jsonl").arrays()
    for Ai, N in zip(A, B, strict=True):
        M = Y @ N @ np.linalg.inv(X)
        cosang = (np.trace(M[:3, :3].T @ Ai[:3, :3]) - 1) / 2
        assert np.degrees(np.arccos(min(1.0, cosang))) < 0.5
        tcp = Ai[:3, :3] @ cal.X[:3, 3] + Ai[:3, 3]
        assert np.linalg.norm((affine @ N)[:3, 3] - tcp) < 1.0


def test_json_export_has_everything_and_loads_back(files):
    path = export(files, "ml.yaml", "json", "c.json")
    d = json.loads(path.read_text())
    for k in ("X", "Y", "Z", "raw", "method", "uncertainty", "distortion", "covariance",
              "parameters", "errors", "session", "provenance", "used", "exported"):
        assert k in d, k
    assert d["provenance"]["versions"]["tmscal"] and len(d["session"]["sha256"]) == 64
    a, b = load_calibration(files / "ml.yaml"), load_calibration(path)
    for k in ("X", "Y", "Z", "X_raw", "Z_raw"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))
    np.testing.assert_allclose(d["used"]["Z"], a.used()["Z"], atol=0)


@pytest.mark.parametrize("calib", ["qr36.yaml", "ml.yaml"])
def test_json_export_carries_the_coil_on_the_marker(files, calib):
    """``CoilToMarker`` (marker ← coil) is X⁻¹ · Y of the calibration file's X and Y, read
    with PyYAML and json; rigid; it maps the coil's origin to where the marker sees it."""
    src = yaml.safe_load((files / calib).read_text())
    d = json.loads(export(files, calib, "json", f"{calib}.json").read_text())
    X, Y = np.asarray(src["X"], dtype=float), np.asarray(src["Y"], dtype=float)
    M = np.asarray(d["CoilToMarker"], dtype=float)
    np.testing.assert_allclose(M, np.linalg.inv(X) @ Y, rtol=0, atol=1e-12)
    np.testing.assert_allclose(M[:3, :3] @ M[:3, :3].T, np.eye(3), atol=1e-12)
    np.testing.assert_array_equal(M[3], [0, 0, 0, 1])
    assert "marker_from_coil" in d["frames"]["CoilToMarker"]
    assert d["frames"]["Y"] == "flange_from_probe"  # the file's own frames kept


def test_json_export_of_a_marker_only_calibration_has_no_coil(files, tmp_path):
    doc = yaml.safe_load((files / "qr36.yaml").read_text())
    for m in (doc, doc["raw"]):
        m.pop("Y")
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    run("export", tmp_path / "m.yaml", "--format", "json", "-o", tmp_path / "m.json")
    d = json.loads((tmp_path / "m.json").read_text())
    assert d["CoilToMarker"] is None and load_calibration(tmp_path / "m.json").Y is None


def test_export_refuses_bad_use(files):
    def fails(*args):
        r = CliRunner().invoke(main, [str(a) for a in args])
        assert r.exit_code != 0
        lines = [ln for ln in r.output.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("error:"), r.output
        return lines[0]

    (files / "exists.json").write_text("{}")
    assert "already exists" in fails("export", files / "qr36.yaml", "--format", "json", "-o",
                                     files / "exists.json")
    assert "input" in fails("export", files / "qr36.yaml", "--format", "json", "-o",
                            files / "qr36.yaml", "--force")
    assert "directory" in fails("export", files, "--format", "json", "-o", files / "x.json")
    assert "easy-handeye" in fails("export", files / "qr36.yaml", "--format", "itk", "-o",
                                   files / "x.tfm", "--easy-handeye2")
    assert "--frame" in fails("export", files / "qr36.yaml", "--format", "easy-handeye", "-o",
                              files / "x.yaml", "--frame", "robot=base")
    fifo = files / "fifo"
    os.mkfifo(fifo)
    assert "FIFO" in fails("export", fifo, "--format", "json", "-o", files / "z.json")
    assert "s.jsonl" in fails("export", files / "s.jsonl", "--format", "json", "-o",
                              files / "y.json")


def test_an_unknown_export_format_is_a_config_error_listing_the_known_ones(files):
    from tmscal.errors import ConfigError
    from tmscal.exports import read_calibration, render

    cf = read_calibration(files / "qr36.yaml")
    with pytest.raises(ConfigError, match=r"^unknown export format 'stl'; known formats: itk, "
                                          r"plus, easy-handeye, invesalius, json$"):
        render("stl", cf)
