"""Property tests of the calibration file's ``noise_model`` section
(tmscal.formats.calibfile.parse_noise_model; docs/lab-day.md): a valid section round-trips
to the same NoiseModel; any corruption of it is one CalibrationError naming the file and a
``noise_model`` key, never another exception."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.errors import CalibrationError
from tmscal.formats.calibfile import parse_noise_model

SRC = "fuzz.yaml"


@st.composite
def sections(draw):
    two = draw(st.booleans())
    q = 12 if two else 6
    L = np.array(draw(st.lists(st.floats(-1, 1), min_size=q * q, max_size=q * q))).reshape(q, q)
    cov = L @ L.T + np.eye(q) * draw(st.floats(1e-4, 1.0))
    d = {"bodies": ["marker", "probe"] if two else ["marker"], "covariance": cov.tolist(),
         "poses": draw(st.integers(0, 1000)), "source": "fuzz"}
    if draw(st.booleans()):
        blocks = ["z", "x", "y"] if two else ["z", "x"]
        d["calibration"] = {"blocks": blocks,
                            "covariance": (np.eye(6 * len(blocks)) * 1e-3).tolist()}
    return d


@given(sections())
@fuzz_settings(60)
def test_a_valid_section_round_trips(d):
    nm = parse_noise_model(d, SRC)
    np.testing.assert_array_equal(nm.cov, np.asarray(d["covariance"]))
    assert list(nm.bodies) == d["bodies"] and nm.n_poses == d["poses"]
    assert (nm.cal_cov is None) == ("calibration" not in d)


junk = (st.none() | st.booleans() | st.integers(-5, 5) | st.floats(allow_nan=True)
        | st.text(max_size=5) | st.lists(st.floats(allow_nan=True), max_size=4)
        | st.just([[1.0, 2.0], [3.0, 4.0]]) | st.just([[-1.0] * 6] * 6))
keys = st.sampled_from(["bodies", "covariance", "poses", "components", "calibration",
                        "calibration.blocks", "calibration.covariance"])


@given(sections(), keys, junk)
@fuzz_settings(150)
def test_a_corrupt_section_is_one_error_naming_the_key(d, key, value):
    if key.startswith("calibration."):
        d.setdefault("calibration", {"blocks": ["z"], "covariance": np.eye(6).tolist()})
        d["calibration"][key.split(".")[1]] = value
    else:
        d[key] = value
    try:
        parse_noise_model(d, SRC)
    except CalibrationError as e:
        assert SRC in str(e) and "noise_model" in str(e) and "\n" not in str(e), str(e)


@given(junk)
@fuzz_settings(30)
def test_a_section_that_is_not_a_mapping_is_refused(value):
    try:
        parse_noise_model(value, SRC)
    except CalibrationError as e:
        assert "noise_model" in str(e)
    else:
        raise AssertionError(f"accepted {value!r}")
