"""The kinematics file (tmscal.formats.kinfile): the calibrated ArmModel survives the YAML and
JSON round trips; every bad document is one CalibrationError naming the file and the key;
hypothesis: any document gives a model or that one error, never another exception."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.calib.selfcal.model import UR5E, VS060, perturb
from tmscal.errors import CalibrationError
from tmscal.formats.kinfile import (
    kinematics_doc,
    kinematics_yaml,
    load_arm,
    parse_kinematics,
    read_kinematics,
)

SRC = "kin.yaml"


def _arm(seed=3, base=UR5E):
    """A model off the nominal in every parameter: DH, base tilt and position, sensor
    mounting, tool, bias."""
    rng = np.random.default_rng(seed)
    p = perturb(base, rng).vector()
    n = 4 * base.n_joints
    p[n:n + 12] += rng.uniform(-0.1, 0.1, 12) * np.tile([1, 1, 1, 100, 100, 100], 2)
    p[n + 12:] += rng.uniform(-2, 2, 10)
    return base.with_vector(p)


def _same(a, b):
    np.testing.assert_allclose(a.vector(), b.vector(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(a.dh, b.dh, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(a.joint_limits_rad, b.joint_limits_rad, rtol=1e-12)
    np.testing.assert_array_equal(a.base, b.base)
    np.testing.assert_array_equal(a.flange_from_sensor, b.flange_from_sensor)
    assert a.name == b.name


@pytest.mark.parametrize("base", [UR5E, VS060])
@pytest.mark.parametrize("how", ["yaml", "json"])
def test_round_trip(tmp_path, base, how):
    arm = _arm(base=base)
    ident = {"parameters": ["theta0_2", "alpha_3", "mg"], "estimate": [0.01, 0.02, 14.0],
             "std": [1e-4, 2e-4, 0.1], "nominal": [0.0, 0.0, 14.7],
             "covariance": np.diag([1e-8, 4e-8, 0.01]), "iterations": np.int64(4)}
    f = tmp_path / f"k.{how}"
    if how == "yaml":
        f.write_text(kinematics_yaml(arm, identification=ident,
                                     session={"path": "s.jsonl", "sha256": "ab"}))
    else:
        f.write_text(json.dumps(kinematics_doc(arm, identification=ident)))
    kf = read_kinematics(f)
    _same(kf.model, arm)
    assert kf.identified == ["theta0_2", "alpha_3", "mg"]
    np.testing.assert_allclose(kf.std, [1e-4, 2e-4, 0.1])
    np.testing.assert_allclose(kf.covariance, np.diag([1e-8, 4e-8, 0.01]))
    assert kf.path == f
    _same(load_arm(f), arm)
    if how == "yaml":
        assert kf.session == {"path": "s.jsonl", "sha256": "ab"}


def test_file_is_in_edge_units():
    """Degrees and mm in the file (docs/conventions.md), radians in the model."""
    doc = kinematics_doc(UR5E)
    assert doc["joints"][0]["alpha_deg"] == pytest.approx(90.0)
    assert doc["joints"][1]["a_mm"] == pytest.approx(-425.0)
    assert doc["joints"][0]["max_deg"] == pytest.approx(360.0)
    assert doc["tool"]["mass_kg"] == pytest.approx(UR5E.tool_mass_kg)


def _doc():
    return yaml.safe_load(kinematics_yaml(_arm()))


def _set(doc, key, value):
    d = doc
    parts = key.replace("]", "").replace("[", ".").split(".")
    for p in parts[:-1]:
        d = d[int(p)] if p.isdigit() else d[p]
    last = parts[-1]
    if value is _DEL:
        del d[int(last) if last.isdigit() else last]
    else:
        d[int(last) if last.isdigit() else last] = value
    return doc


_DEL = object()


@pytest.mark.parametrize("key, value, words", [
    ("format", "tmscal-calibration", "tmscal-kinematics"),
    ("version", 2, "version 1"),
    ("arm", "", "arm"),
    ("joints", [], "1 to 12 joints"),
    ("joints[2].d_mm", "12", "expected a number"),
    ("joints[2].d_mm", 1e9, "outside"),
    ("joints[1].alpha_deg", _DEL, "missing"),
    ("joints[1].offset", 1.0, "unknown key"),
    ("joints[4].min_deg", 400.0, "not above min_deg"),
    ("base", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]], "base"),
    ("flange_from_sensor", [[1, 0, 0]], "4×4"),
    ("tool.mass_kg", -1.0, "outside"),
    ("tool.cog_mm", [0, 0], "3 numbers"),
    ("bias.torque_nm", [0, 0, math.inf], "finite"),
    ("bias.force", [0, 0, 0], "unknown key"),
    ("extra", 1, "unknown key"),
    ("identification", {"parameters": ["theta0_9"]}, "not a parameter"),
    ("identification", {"parameters": ["mg"], "std": [-1.0]}, "negative"),
    ("identification", {"parameters": ["mg", "cog_x"], "covariance": [[1, 2], [0, 1]]},
     "symmetric"),
])
def test_bad_document_names_the_key(key, value, words):
    doc = _set(_doc(), key, value)
    with pytest.raises(CalibrationError) as e:
        parse_kinematics(doc, SRC)
    msg = str(e.value)
    assert msg.startswith(SRC) and words in msg and "\n" not in msg
    top = key.split(".")[0].split("[")[0]
    if top not in ("format", "version", "base", "flange_from_sensor"):
        assert f"'{top}" in msg


def test_bad_files(tmp_path):
    with pytest.raises(CalibrationError, match="cannot read .*No such file"):
        read_kinematics(tmp_path / "missing.yaml")
    with pytest.raises(CalibrationError, match="not a regular file"):
        read_kinematics(tmp_path)
    f = tmp_path / "bin.yaml"
    f.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(CalibrationError, match="UTF-8"):
        read_kinematics(f)
    f.write_text("a: &a [*a]\n")
    with pytest.raises(CalibrationError, match=str(f)):
        read_kinematics(f)
    f.write_text("joints: [\n")
    with pytest.raises(CalibrationError, match="invalid YAML"):
        read_kinematics(f)


# --- properties -------------------------------------------------------------------------------

def check(doc):
    try:
        return parse_kinematics(doc, SRC)
    except CalibrationError as e:
        assert str(e).startswith(SRC) and "\n" not in str(e)
        return None


finite = st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False)
json_leaf = (st.none() | st.booleans() | st.integers(-10**20, 10**20) | finite
             | st.floats() | st.text(max_size=8))
trees = st.recursive(json_leaf, lambda c: st.lists(c, max_size=5)
                     | st.dictionaries(st.text(max_size=6), c, max_size=5), max_leaves=40)


@given(trees)
@fuzz_settings(200)
def test_any_document_is_a_model_or_one_error(doc):
    check(doc)


KEYS = ["format", "version", "arm", "joints", "base", "flange_from_sensor", "tool", "bias",
        "identification", "session", "joints[0]", "joints[5].a_mm", "joints[3].max_deg",
        "tool.cog_mm", "bias.force_n", "tool.mass_kg"]
BASE_DOC = _doc()


@given(st.sampled_from(KEYS), trees)
@fuzz_settings(300)
def test_one_key_replaced_by_anything(key, value):
    kf = check(_set(copy.deepcopy(BASE_DOC), key, value))
    if kf is not None:  # whatever was accepted is a valid model
        assert np.isfinite(kf.model.vector()).all()
        R = kf.model.base[:3, :3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-4)


@given(st.lists(st.tuples(finite, finite, finite, finite), min_size=1, max_size=12),
       st.floats(0, 100), st.lists(finite, min_size=3, max_size=3))
@fuzz_settings(100)
def test_valid_models_round_trip(rows, mass, cog):
    """Any DH table within the file's bounds (angles reduced to ±180°) reads back."""
    dh = np.array([[math.radians(t % 360 - 180), d / 10, a / 10, math.radians(al % 360 - 180)]
                   for t, d, a, al in rows])
    lim = np.tile([-math.pi, math.pi], (len(dh), 1))
    from tmscal.calib.selfcal.model import ArmModel
    arm = ArmModel(name="x", dh=dh, tool_mass_kg=mass, tool_cog_mm=np.array(cog) / 10,
                   joint_limits_rad=lim)
    kf = parse_kinematics(yaml.safe_load(kinematics_yaml(arm)), SRC)
    np.testing.assert_allclose(kf.model.dh, arm.dh, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(kf.model.tool_mass_kg, arm.tool_mass_kg, rtol=1e-15)
    np.testing.assert_allclose(kf.model.tool_cog_mm, arm.tool_cog_mm, rtol=1e-15)


# --- selfcal identify writes it ---------------------------------------------------------------

def selfcal_session(path, pair, n=50, sigma=(0.05, 0.01), samples=25, seed=4, spreads=True):
    """A session as `selfcal acquire` records it, made here from the true arm's gravity
    wrench plus Gaussian noise of the averaged reading ``sigma`` (N, N·m)."""
    from tmscal.calib.selfcal.model import wrench
    from tmscal.session import PoseRecord, make_header, write_session

    rng = np.random.default_rng(seed)
    q = np.array(pair.home_q) + rng.uniform(-0.8, 0.8, (n, 6))
    s = np.repeat(sigma, 3)
    w = wrench(pair.true, q) + rng.normal(0.0, 1.0, (n, 6)) * s
    recs = [PoseRecord(index=i, A=pair.reported(q[i]), B=None, joints_rad=q[i].tolist(),
                       wrench=w[i].tolist(), samples={"A": 1, "wrench": samples},
                       wrench_spread=(s * np.sqrt(samples)).tolist() if spreads else None)
            for i in range(n)]
    write_session(path, make_header(["ft"], selfcal={"arm": pair.nominal.name}), recs)
    return q


def test_identify_writes_a_kinematics_file_closer_to_the_truth(tmp_path):
    """`tmscal selfcal identify --form kept` on a session of the true arm's wrenches (seeded
    noise; the paper's protocol: errors on the columns the fit keeps): the file reads back;
    every hidden error shrinks in aggregate; its σ are those of the noise (the reduced χ² near
    1); the outputs are refused when they exist (no --force)."""
    from click.testing import CliRunner

    from tmscal.calib.selfcal.identify import position_errors
    from tmscal.cli import main
    from tmscal.sim.arm import make_arm

    pair = make_arm("ur5e", "paper", 11)
    s_path, k_path = tmp_path / "sc.jsonl", tmp_path / "kin.yaml"
    q = selfcal_session(s_path, pair)
    args = ["selfcal", "identify", str(s_path), "-o", str(k_path), "--form", "kept"]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert "converged" in r.output and "not identified: base_yaw: zero column" in r.output
    kf = read_kinematics(k_path)
    names = pair.nominal.parameter_names()
    hidden = [names.index(n) for n in pair.perturbed]
    d_est = (kf.model.vector() - pair.true.vector())[hidden]
    d_nom = (pair.nominal.vector() - pair.true.vector())[hidden]
    assert np.linalg.norm(d_est) < 0.2 * np.linalg.norm(d_nom)
    assert (position_errors(pair.true, kf.model, q).mean()
            < 0.2 * position_errors(pair.true, pair.nominal, q).mean())
    ident = kf.doc["identification"]
    assert 0.5 < ident["reduced_chi2"] < 2.0   # 300 residuals, 22 parameters
    assert kf.session["sha256"] and kf.identified == ident["parameters"]
    assert ident["form"] == "kept"
    again = CliRunner().invoke(main, args)
    assert again.exit_code == 2 and "--force" in again.output


@pytest.mark.parametrize("seed", [11, 2])
def test_identify_default_is_the_kinematic_estimator_with_wrench_rows_only(tmp_path, seed):
    """The default form: errors on every length and angle (``all``), so the wrench sees part
    of them only in combinations and the lengths not at all. The written arm is the one
    kinematic estimator's (wrench rows, no tracker rows): it fits the wrenches as well as the
    paper's kept-columns fit; no length moves from nominal (no wrench sees one: the prior keeps
    it, and the file says why); its deviations are the estimator's own, called directly on the
    same data; after a hand/eye calibration absorbs what no wrench sees, its TCP error is
    below the nominal arm's."""
    from click.testing import CliRunner

    from tmscal.calib.kinematics.estimate import fit_kinematics
    from tmscal.calib.kinematics.identifiability import ZERO_WRENCH_REASON
    from tmscal.calib.kinematics.levels import Tolerances
    from tmscal.calib.kinematics.wrench import WrenchData
    from tmscal.calib.selfcal.model import wrench
    from tmscal.calib.selfcal.study.compare import absorbed_errors
    from tmscal.cli import main
    from tmscal.session import read_session
    from tmscal.sim.arm import make_arm
    from tmscal.solving.selfcal import identify_session

    pair = make_arm("ur5e", "all", seed)
    s_path, k_path = tmp_path / "sc.jsonl", tmp_path / "kin.yaml"
    q = selfcal_session(s_path, pair)
    r = CliRunner().invoke(main, ["selfcal", "identify", str(s_path), "-o", str(k_path)])
    assert r.exit_code == 0, r.output
    assert "the MAP model of every deviation" in r.output and "tool: mass" in r.output
    kf = read_kinematics(k_path)
    ident = kf.doc["identification"]
    assert ident["form"] == "map" and ident["method"] == "wrench"
    kept = identify_session(read_session(s_path), "ur5e", form="kept")
    w = np.array([p.wrench for p in read_session(s_path).poses])
    rms_map = np.sqrt(np.mean((wrench(kf.model, q) - w) ** 2, axis=0))
    assert np.all(rms_map <= 1.05 * kept.rms + 1e-9)
    lengths = [f"{k}_{i}" for i in range(1, 7) for k in ("d", "a")]
    np.testing.assert_allclose([kf.model.deviation(n) for n in lengths],
                               [pair.nominal.deviation(n) for n in lengths], rtol=0, atol=1e-12)
    unseen = {t for c in ident["unidentified"] if c["reason"] == ZERO_WRENCH_REASON
              for t in c["terms"]}
    assert set(lengths) <= unseen
    sig = np.array(list(ident["sigma"].values()))
    direct = fit_kinematics(q, [], pair.nominal, "full", ([], np.eye(4)), {},
                            Tolerances(2.0, 1.0), wrench=WrenchData.make(w, sig, len(q)))
    np.testing.assert_allclose([kf.model.deviation(n) - pair.nominal.deviation(n)
                                for n in direct.names], direct.delta, atol=1e-9)
    assert (absorbed_errors(pair.true, kf.model, q).mean()
            < 0.9 * absorbed_errors(pair.true, pair.nominal, q).mean())


def test_identify_without_spreads_needs_sigma(tmp_path):
    from click.testing import CliRunner

    from tmscal.cli import main
    from tmscal.sim.arm import make_arm

    s_path = tmp_path / "sc.jsonl"
    selfcal_session(s_path, make_arm("ur5e", "none", 0), n=20, spreads=False)
    r = CliRunner().invoke(main, ["selfcal", "identify", str(s_path), "-o",
                                  str(tmp_path / "k.yaml")])
    assert r.exit_code == 1 and "--sigma" in r.output and "no wrench spreads" in r.output
    r = CliRunner().invoke(main, ["selfcal", "identify", str(s_path), "-o",
                                  str(tmp_path / "k.yaml"), "--sigma", "0.05", "0.01"])
    assert r.exit_code == 0, r.output
    assert "from --sigma" in r.output


def test_modified_dh_and_flange_round_trip(tmp_path):
    """A Franka arm (modified DH, the flange 107 mm past the last DH frame) keeps its
    convention and flange through the file: the same flange poses after reading."""
    from tmscal.calib.selfcal.model import NOMINAL, forward
    arm = _arm(base=NOMINAL["fr3"])
    f = tmp_path / "fr3.yaml"
    f.write_text(kinematics_yaml(arm))
    back = load_arm(f)
    assert back.convention == "modified"
    np.testing.assert_allclose(back.flange, arm.flange, atol=1e-12)
    q = np.random.default_rng(1).uniform(-1.0, 1.0, (5, 7))
    np.testing.assert_allclose(forward(back, q), forward(arm, q), atol=1e-9)


def test_a_file_without_convention_or_flange_is_standard_dh():
    doc = _doc()
    doc.pop("convention")
    doc.pop("flange")
    kf = parse_kinematics(doc, SRC)
    assert kf.model.convention == "standard"
    np.testing.assert_array_equal(kf.model.flange, np.eye(4))


@pytest.mark.parametrize("key, value", [("convention", "craig"), ("flange", [[1, 0], [0, 1]])])
def test_bad_convention_or_flange_names_the_key(key, value):
    doc = _doc()
    doc[key] = value
    with pytest.raises(CalibrationError, match=f"kin.yaml: key '{key}"):
        parse_kinematics(doc, SRC)
