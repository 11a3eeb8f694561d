"""CLI through click's runner: simulate → solve → study, and the bad-input paths (one
``error:`` line, non-zero exit, nothing written over)."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tmscal.cli import main


@pytest.fixture(scope="module")
def sim_session(tmp_path_factory):
    p = tmp_path_factory.mktemp("cli") / "sim.jsonl"
    r = CliRunner().invoke(main, ["simulate", "-o", str(p), "--poses", "120", "--seed", "3"])
    assert r.exit_code == 0, r.output
    return p


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_solve_json_recovers_truth(sim_session):
    r = run("solve", sim_session, "--train", 60, "--json")
    assert r.exit_code == 0, r.output
    res = json.loads(r.output)
    assert res["method"] == "qr36" and res["n_solve"] == 60 and res["n_test"] == 60
    assert res["errors_on"] == "held-out"
    for k in ("X", "Y", "Z"):
        assert np.asarray(res[k]).shape == (4, 4)
        assert res["truth"][k]["trans_mm"] < 0.5 and res["truth"][k]["rot_deg"] < 0.1
    assert res["truth"]["coil_placement_mm"] < 0.3
    e = res["errors"]
    assert {"e_t_mm", "theta_t_deg", "marker", "probe"} <= set(e)
    assert "trans_mm" in e["marker"] and "rot_deg" in e["probe"]


def test_solve_qr24_reports_ez_cross_validated_by_default(sim_session):
    res = json.loads(run("solve", sim_session, "--method", "qr24", "--json").output)
    assert res["errors_on"] == "cross-validated (5 folds)" and res["n_test"] == 120
    assert res["n_solve"] == 120
    assert res["cv"] == {"folds": 5, "split": "contiguous", "fold_sizes": [24] * 5}
    assert "e_z_mm" in res["errors"] and "theta_z_deg" in res["errors"]
    assert res["errors_sd"]["e_z_mm"] > 0 and res["errors_sd"]["marker"]["trans_mm"] > 0


def test_solve_in_sample_only_on_request_and_labelled(sim_session):
    res = json.loads(run("solve", sim_session, "--in-sample", "--json").output)
    assert res["errors_on"] == "in-sample" and res["n_test"] == 120
    assert res["errors_sd"] is None and res["cv"] is None
    r = run("solve", sim_session, "--in-sample")
    assert r.exit_code == 0 and "errors: IN-SAMPLE, on the same 120 poses" in r.output
    res3 = json.loads(run("solve", sim_session, "--folds", 3, "--json").output)
    assert res3["errors_on"] == "cross-validated (3 folds)"
    assert res3["cv"]["fold_sizes"] == [40, 40, 40]
    msg = _one_error_line(run("solve", sim_session, "--train", 60, "--in-sample"))
    assert "--train" in msg and "--in-sample" in msg


def test_solve_human_table_and_yaml(sim_session, tmp_path):
    out = tmp_path / "cal.yaml"
    png = tmp_path / "res.png"
    r = run("solve", sim_session, "--train", 60, "-o", out, "--plot", png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert r.exit_code == 0, r.output
    assert "coil placement error, mm over 120 targets: mean" in r.output and "e_t" in r.output
    assert "errors: held out on the 60 poses after the first 60 (--train)" in r.output
    assert "probe    E = (AY)⁻¹ZC" in r.output and "legend" in r.output
    import yaml
    doc = yaml.safe_load(out.read_text())
    assert doc["method"] == "qr36" and len(doc["session"]["sha256"]) == 64
    assert np.asarray(doc["Y"]).shape == (4, 4)
    assert doc["poses"]["errors_on"] == "held-out" and doc["outlier_poses"] == []
    # the plot obeys the one output rule: an existing file is refused and left as it was
    before = png.read_bytes()
    assert "already exists" in _one_error_line(run("solve", sim_session, "--plot", png))
    assert png.read_bytes() == before


def test_study_json_and_plot(sim_session, tmp_path):
    png = tmp_path / "f.png"
    r = run("study", sim_session, "--n-max", 30, "--json", "--plot", png)
    assert r.exit_code == 0, r.output
    res = json.loads(r.output)
    assert res["n"][0] == 5 and res["n"][-1] == 30 and res["n_test"] == 90
    assert set(res["table"]) == {"qr24", "qr36"}
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert 0 < res["noise_floor"]["e_t_mm"] <= min(res["curves"]["qr36"]["e_t_mm"])
    before = png.read_bytes()
    assert "already exists" in _one_error_line(run("study", sim_session, "--n-max", 30,
                                                   "--plot", png))
    assert png.read_bytes() == before


def _one_error_line(r):
    assert r.exit_code != 0
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.output
    assert "Traceback" not in r.output
    return lines[0]


def test_bad_inputs_give_one_line(sim_session, tmp_path):
    assert "at least 3 poses" in _one_error_line(run("solve", sim_session, "--train", 2))
    assert "No such file" in _one_error_line(run("solve", tmp_path / "none.jsonl"))
    bad = tmp_path / "bad.jsonl"
    lines = sim_session.read_text().splitlines()
    lines[4] = lines[4][:40] + "}"
    bad.write_text("\n".join(lines) + "\n")
    r = run("solve", bad)  # a damaged middle line is skipped, named, and the rest solved
    assert r.exit_code == 0, r.output
    warn = [ln for ln in r.output.splitlines() if ln.startswith("warning:")]
    assert len(warn) == 1 and "line 5" in warn[0] and "damaged" in warn[0]
    assert "line 5" in _one_error_line(run("solve", bad, "--strict"))
    assert "unknown method" in _one_error_line(run("study", sim_session, "--methods", "foo"))


def test_marker_only_qr36_and_nothing_written_over(tmp_path):
    m = tmp_path / "m.jsonl"
    assert run("simulate", "-o", m, "--poses", 20, "--marker-only").exit_code == 0
    out = tmp_path / "cal.yaml"
    out.write_text("keep me\n")
    msg = _one_error_line(run("solve", m, "-o", out))
    assert "already exists" in msg and "--force" in msg
    assert out.read_text() == "keep me\n"
    msg = _one_error_line(run("solve", m, "-o", tmp_path / "new.yaml"))
    assert "marker-only" in msg and "qr24" in msg
    assert not (tmp_path / "new.yaml").exists()
    assert run("solve", m, "--method", "qr24").exit_code == 0
    before = m.read_bytes()
    assert "already exists" in _one_error_line(run("simulate", "-o", m))
    assert m.read_bytes() == before


def test_degenerate_rotations(tmp_path):
    from tmscal import geometry as g
    from tmscal.session import make_header, records_from_arrays, write_session
    A = np.stack([g.make_pose(g.rot_z(a), [a, 2 * a, 0]) for a in np.linspace(0, 1, 8)])
    p = write_session(tmp_path / "d.jsonl", make_header(["marker", "probe"]),
                      records_from_arrays(A, A, A))
    assert "rotation diversity" in _one_error_line(run("solve", p))


def test_help_explains():
    r = run("--help")
    assert r.exit_code == 0 and "flange" in r.output and "mm" in r.output
    for cmd in ("simulate", "solve", "study", "demo"):
        assert run(cmd, "--help").exit_code == 0


@pytest.mark.parametrize("kin, ur, denso", [(False, "mock-ur-polaris.yaml",
                                             "mock-denso-polaris.yaml"),
                                            (True, "mock-ur-polaris-kin.yaml",
                                             "mock-denso-polaris-kin.yaml")])
def test_demo_runs_on_the_mock_denso_where_ur_rtde_is_missing(monkeypatch, capsys, kin, ur,
                                                             denso) -> None:
    """A plain ``pip install tmscal`` where PyPI has no ur_rtde wheel (no such dependency
    there): the default demo takes the mock DENSO rig (no extra needed) and says why; with
    ur_rtde importable it keeps the mock UR. Both configs load from the package data."""
    from importlib.resources import files

    from tmscal.cli.demo import demo_config_name
    from tmscal.config import load_config

    assert demo_config_name(kin) == ur
    assert capsys.readouterr().err == ""
    for mod in ("rtde_control", "rtde_receive"):
        monkeypatch.setitem(sys.modules, mod, None)  # not importable, as when not installed
    assert demo_config_name(kin) == denso
    assert "ur_rtde is not installed" in capsys.readouterr().err
    cfg = load_config(Path(str(files("tmscal.data") / "configs" / denso)))
    assert cfg.robot.driver == "denso" and cfg.mock is not None
