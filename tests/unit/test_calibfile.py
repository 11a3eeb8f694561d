"""tmscal.exports.load_calibration: the file `tmscal solve -o` writes (and the json export)
back into the Calibration `solve` returned; bad files are one CalibrationError naming the file
and key."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tmscal.calib import Applied, solve
from tmscal.cli import main
from tmscal.errors import CalibrationError
from tmscal.exports import load_calibration
from tmscal.session import read_session


def run(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    return r


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("calib")
    run("simulate", "-o", d / "s.jsonl", "--poses", 60, "--seed", 4)
    run("simulate", "-o", d / "d.jsonl", "--poses", 60, "--seed", 5, "--tracker-scale", 1.001)
    run("solve", d / "s.jsonl", "-o", d / "qr36.yaml", "--folds", 2)
    run("solve", d / "s.jsonl", "-o", d / "qr24.yaml", "--method", "qr24", "--orthonormal",
        "--folds", 2)
    run("solve", d / "d.jsonl", "-o", d / "ml.yaml", "--method", "ml", "--option",
        "distortion=scale", "--folds", 2)
    run("export", d / "ml.yaml", "--format", "json", "-o", d / "ml.json")
    return d


def _arrays(path):
    A, B, C, _ = read_session(path).arrays(need_probe=True)
    return A, B, C


def _same(a, b):
    for k in ("X", "Y", "Z", "X_raw", "Y_raw", "Z_raw", "Z_probe", "Z_probe_raw"):
        va, vb = getattr(a, k), getattr(b, k)
        assert (va is None) == (vb is None), k
        if va is not None:
            np.testing.assert_allclose(vb, va, rtol=0, atol=1e-12, err_msg=k)
    assert (a.method, a.n_poses, a.applied) == (b.method, b.n_poses, b.applied)


@pytest.mark.parametrize("name,method,opts", [
    ("qr36.yaml", "qr36", {}),
    ("qr24.yaml", "qr24", {"orthonormal": True}),
])
def test_load_gives_the_calibration_solve_returns(files, name, method, opts):
    A, B, C = _arrays(files / "s.jsonl")
    cal = solve(A, B, C, method=method, **opts)
    back = load_calibration(files / name)
    _same(cal, back)
    assert back.applied == (Applied.ORTHONORMAL if opts else Applied.RAW)
    # the loaded calibration applies the same matrices: the same errors on every pose
    e0, e1 = cal.errors(A, B, C), back.errors(A, B, C)
    assert e1["e_t_mm"] == pytest.approx(e0["e_t_mm"], rel=1e-12)
    if method == "qr24":
        assert back.Z_probe is not None and e1["e_z_mm"] == pytest.approx(e0["e_z_mm"])


@pytest.mark.parametrize("name", ["ml.yaml", "ml.json"])
def test_load_ml_keeps_covariance_uncertainty_and_distortion(files, name):
    A, B, C = _arrays(files / "d.jsonl")
    cal = solve(A, B, C, method="ml", distortion="scale")
    back = load_calibration(files / name)
    _same(cal, back)
    np.testing.assert_allclose(back.covariance, cal.covariance, rtol=1e-12)
    assert back.extra["parameters"] == cal.extra["parameters"]
    assert back.distortion["model"] == "scale"
    np.testing.assert_allclose(back.distortion["matrix"], cal.distortion["matrix"], rtol=1e-12)
    for k in ("coil_centre_mm", "coil_axis_deg"):
        assert back.uncertainty[k]["p95"] == pytest.approx(cal.uncertainty[k]["p95"])
    # with a distortion the errors undistort first: the loaded one does the same
    assert back.errors(A, B, C)["e_t_mm"] == pytest.approx(cal.errors(A, B, C)["e_t_mm"])


def _doc(files, name="qr36.yaml"):
    return yaml.safe_load((files / name).read_text())


def _bad(tmp_path, text, *needles):
    p = tmp_path / "bad.yaml"
    p.write_text(text) if isinstance(text, str) else p.write_bytes(text)
    with pytest.raises(CalibrationError) as e:
        load_calibration(p)
    msg = str(e.value)
    assert str(p) in msg and "\n" not in msg
    for n in needles:
        assert n in msg, msg
    return msg


def test_bad_files_name_the_file_and_key(files, tmp_path):
    d = _doc(files)
    _bad(tmp_path, "- 1\n- 2\n", "expected a mapping")
    _bad(tmp_path, "", "expected a mapping")
    _bad(tmp_path, "X: [\n", "invalid YAML", "line")
    _bad(tmp_path, b"\xff\xfe bad", "UTF-8")
    _bad(tmp_path, yaml.safe_dump({**d, "format": "other"}), "'format'")
    _bad(tmp_path, yaml.safe_dump({**d, "version": 2}), "'version'")
    _bad(tmp_path, yaml.safe_dump({k: v for k, v in d.items() if k != "Z"}), "'Z'", "missing")
    _bad(tmp_path, yaml.safe_dump({**d, "X": d["X"][:3]}), "'X'", "4×4")
    shear = [row[:] for row in d["X"]]
    shear[0][1] += 0.01
    _bad(tmp_path, yaml.safe_dump({**d, "X": shear}), "'X'", "not rigid")
    last = [row[:] for row in d["Z"]]
    last[3] = [0, 0, 1, 1]
    _bad(tmp_path, yaml.safe_dump({**d, "Z": last}), "'Z'", "last row")
    text = yaml.safe_dump({**d, "Y": [[".nan"] * 4] * 4}).replace("'.nan'", ".nan")
    _bad(tmp_path, text, "Y[0][0]", "finite")
    word = [row[:] for row in d["Z"]]
    word[1][2] = "one"
    _bad(tmp_path, yaml.safe_dump({**d, "Z": word}), "Z[1][2]", "not a number")
    big = {**d, "raw": {**d["raw"], "Z": [[1e6, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                          [0, 0, 0, 1]]}}
    _bad(tmp_path, yaml.safe_dump(big), "raw.Z", "singular or implausibly large")
    _bad(tmp_path, yaml.safe_dump({**d, "applied": "both"}), "'applied'")
    _bad(tmp_path, yaml.safe_dump({**d, "distortion": {"matrix": [[1, 0], [0, 1]]}}),
         "distortion.matrix", "3×3")
    _bad(tmp_path, yaml.safe_dump({**d, "covariance": [[1.0, 0.0]]}), "covariance", "square")
    _bad(tmp_path, yaml.safe_dump({**d, "parameters": ["a"], "covariance": [[1.0, 0.0],
                                                                            [0.0, 1.0]]}),
         "'parameters'", "1 names")
    _bad(tmp_path, json.dumps({**d, "X": [[float("nan")] * 4] * 4}), "invalid JSON")


def test_yaml_bombs_and_recursion_are_refused(tmp_path):
    lol = ["a: &a [x, x, x, x, x, x, x, x, x, x]"]
    for i in range(1, 9):
        lol.append(f"{chr(97 + i)}: &{chr(97 + i)} [" + ", ".join([f"*{chr(96 + i)}"] * 10)
                   + "]")
    _bad(tmp_path, "\n".join(lol) + "\n", "100,000 values")
    _bad(tmp_path, "a: &r [*r]\n", "itself")
    _bad(tmp_path, "[" * 5000 + "]" * 5000, "YAML")


def test_a_missing_or_huge_file(tmp_path):
    with pytest.raises(CalibrationError, match="cannot read .*No such file"):
        load_calibration(tmp_path / "nope.yaml")
    with pytest.raises(CalibrationError, match="not a regular file"):
        load_calibration(tmp_path)
    p = tmp_path / "huge.yaml"
    p.write_text("# " + "x" * 4_100_000)
    with pytest.raises(CalibrationError, match="larger than"):
        load_calibration(p)


def test_old_files_without_z_probe_still_load(files, tmp_path):
    d = _doc(files, "qr24.yaml")
    d.pop("Z_probe")
    p = tmp_path / "old.yaml"
    p.write_text(yaml.safe_dump(d))
    back = load_calibration(p)
    # projected from the raw one: rigid, and within the raw one's distance from rigid
    R = back.Z_probe[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.abs(back.Z_probe[:3, :3] - back.Z_probe_raw[:3, :3]).max() < 1e-2


def test_solve_calib_in_process_refusals_and_same_session_warning(files):
    def one_line(*args):
        r = CliRunner().invoke(main, [str(a) for a in args])
        assert r.exit_code != 0
        lines = [ln for ln in r.output.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("error:"), r.output
        return lines[0]

    s, c = files / "s.jsonl", files / "qr36.yaml"
    assert "--calib" in one_line("solve", s, "--calib", c, "--train", 20)
    assert "--calib" in one_line("solve", s, "--calib", c, "-o", files / "new.yaml")
    assert "--calib" in one_line("solve", s, "--calib", c, "--method", "ml")
    assert "nope.yaml" in one_line("solve", s, "--calib", files / "nope.yaml")
    assert "d.jsonl" in one_line("solve", s, "--calib", files / "d.jsonl")
    out = run("solve", s, "--calib", c).output
    assert "WARNING: this is the session the calibration was solved on" in out
    assert "in-sample" in out
