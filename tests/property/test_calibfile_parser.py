"""Property tests of the calibration file parser (tmscal.formats.calibfile): any text or
document gives a Calibration or one CalibrationError naming the file, never another
exception; rigid matrices survive the YAML and JSON round trips exactly."""

from __future__ import annotations

import json

import numpy as np
import yaml
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.errors import CalibrationError
from tmscal.formats.calibfile import parse_calibration
from tmscal.formats.textfile import load_text as parse_document
from tmscal.geometry import make_pose, matrix_from_rotvec

SRC = "fuzz.yaml"

finite = st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False)
rotvec = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3)
trans = st.lists(st.floats(-3000, 3000), min_size=3, max_size=3)


@st.composite
def poses(draw):
    return make_pose(matrix_from_rotvec(np.array(draw(rotvec))), np.array(draw(trans)))


def valid_doc(X, Z, Y=None, **extra):
    return {"format": "tmscal-calibration", "version": 1, "method": "qr36", "applied": "raw",
            "poses": {"solve": 10}, "X": X.tolist(), "Z": Z.tolist(),
            "Y": None if Y is None else Y.tolist(), **extra}


def check(doc):
    try:
        return parse_calibration(doc, SRC)
    except CalibrationError as e:
        assert SRC in str(e) and "\n" not in str(e)
        return None


@given(poses(), poses(), poses(), st.sampled_from(["yaml", "json"]))
@fuzz_settings(100)
def test_rigid_matrices_round_trip_exactly(X, Y, Z, how):
    doc = valid_doc(X, Z, Y)
    text = yaml.safe_dump(doc) if how == "yaml" else json.dumps(doc)
    cal = parse_calibration(parse_document(text, SRC), SRC)
    np.testing.assert_array_equal(cal.X, X)
    np.testing.assert_array_equal(cal.Y, Y)
    np.testing.assert_array_equal(cal.Z_raw, Z)  # no raw given: the orthonormal ones


json_leaf = st.none() | st.booleans() | st.integers(-10**20, 10**20) | finite | st.text(max_size=8)
trees = st.recursive(json_leaf, lambda c: st.lists(c, max_size=5)
                     | st.dictionaries(st.text(max_size=6), c, max_size=5), max_leaves=40)


@given(trees)
@fuzz_settings(300)
def test_any_document_is_a_calibration_or_one_error(doc):
    check(doc)


KEYS = ["format", "version", "method", "applied", "poses", "X", "Y", "Z", "Z_probe", "raw",
        "covariance", "parameters", "uncertainty", "distortion"]


@given(poses(), poses(), st.sampled_from(KEYS), trees)
@fuzz_settings(300)
def test_one_key_replaced_by_anything(X, Z, key, value):
    doc = valid_doc(X, Z)
    doc[key] = value
    cal = check(doc)
    if cal is not None and key in ("X", "Z"):  # accepted only as a rigid 4×4
        M = getattr(cal, key)
        np.testing.assert_allclose(M[:3, :3] @ M[:3, :3].T, np.eye(3), atol=1e-4)


@given(poses(), poses(), st.integers(0, 3), st.integers(0, 3),
       st.one_of(finite, st.just(float("nan")), st.just(float("inf")), st.text(max_size=3),
                 st.none(), st.booleans()))
@fuzz_settings(300)
def test_one_entry_of_a_matrix_replaced(X, Z, i, j, v):
    doc = valid_doc(X, Z)
    doc["Z"][i][j] = v
    cal = check(doc)
    if cal is not None:
        assert np.isfinite(cal.Z).all()


@given(st.text(max_size=300))
@fuzz_settings(300)
def test_any_text_parses_or_fails_cleanly(text):
    try:
        doc = parse_document(text, SRC)
    except CalibrationError as e:
        assert SRC in str(e)
        return
    check(doc)
