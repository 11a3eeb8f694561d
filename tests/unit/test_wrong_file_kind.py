"""A file of the wrong kind gets one line saying what the file is and what the command expects
(issue 24, item 3): a session given to track/robot/acquire/mock, a rig config or a calibration
given to solve/report, a session or a config or an export given as --calib, a calibration given
as --kinematics; a short session says what is wrong without naming an option that was not
given; ``selfcal simulate --seed -1`` names the option. Every file here is written by tmscal's
own commands (simulate, solve -o, export) or is a shipped config."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.filekind import KINDS, sniff

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "configs" / "mock-ur-polaris.yaml"


def _run(*args: object) -> tuple[int, list[str]]:
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r.exit_code, [ln for ln in r.stderr.splitlines() if ln.strip()]


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """kind → a file of that kind, written by tmscal (the config is the shipped one)."""
    d = tmp_path_factory.mktemp("kinds")
    out = {"config": CONFIG, "session": d / "sim.jsonl", "short": d / "short.jsonl",
           "calibration": d / "calib.yaml"}
    for name, n in (("sim.jsonl", 30), ("short.jsonl", 2)):
        code, err = _run("simulate", "-o", d / name, "--poses", n, "--seed", 1)
        assert code == 0, err
    code, err = _run("solve", out["session"], "-o", out["calibration"])
    assert code == 0, err
    for fmt, name in (("itk", "Z.tfm"), ("plus", "plus.xml"), ("easy-handeye", "eh.yaml"),
                      ("invesalius", "robot.rbtf"), ("json", "calib.json")):
        code, err = _run("export", out["calibration"], "--format", fmt, "-o", d / name)
        assert code == 0, err
        out["json-export" if fmt == "json" else fmt] = d / name
    code, err = _run("report", out["session"], "-o", d / "report.html")
    assert code == 0, err
    out["report"] = d / "report.html"
    return out


def test_each_kind_of_tmscal_file_is_recognised(files):
    for kind, path in files.items():
        want = {"short": "session", "json-export": "calibration"}.get(kind, kind)
        assert sniff(path.read_text()) == want, path
    assert sniff("hello: world\n") is None
    assert sniff("") is None
    assert sniff("{not json at all\n") is None


# (command line with {session}, {config}, … for the files, what the file is, what is expected)
CASES = [
    ("track {session} --frames 1", "session", "tmscal track expects a rig config"),
    ("robot {session}", "session", "tmscal robot expects a rig config"),
    ("acquire {session} -o {d}/new.jsonl", "session", "tmscal acquire expects a rig config"),
    ("acquire {calibration} -o {d}/new.jsonl", "calibration",
     "tmscal acquire expects a rig config"),
    ("mock {json-export}", "calibration", "tmscal mock expects a rig config"),
    ("solve {config}", "config", "tmscal solve expects a tmscal session"),
    ("solve {calibration}", "calibration", "tmscal solve expects a tmscal session"),
    ("report {calibration} -o {d}/r.html", "calibration",
     "tmscal report expects a tmscal session"),
    ("solve {session} --calib {session}", "session", "tmscal solve expects a calibration file"),
    ("solve {session} --calib {config}", "config", "tmscal solve expects a calibration file"),
    ("solve {session} --calib {itk}", "itk", "tmscal solve expects a calibration file"),
    ("export {plus} --format itk -o {d}/z.tfm", "plus",
     "tmscal export expects a calibration file"),
    ("stream {config} --calib {easy-handeye}", "easy-handeye",
     "tmscal stream expects a calibration file"),
    ("solve {session} --calib {invesalius}", "invesalius",
     "tmscal solve expects a calibration file"),
    ("solve {session} --calib {report}", "report", "tmscal solve expects a calibration file"),
    ("solve {session} --kinematics {calibration}", "calibration",
     "tmscal solve expects a kinematics file"),
    ("selfcal identify {calibration} -o {d}/kin.yaml", "calibration",
     "tmscal selfcal identify expects a tmscal session"),
]


def _wrong_file(line: str) -> str:
    """The placeholder of the file given in the wrong place: the last one on the line."""
    return [k for k in re.findall(r"\{([\w-]+)\}", line) if k != "d"][-1]


@pytest.mark.parametrize("line, kind, expects", CASES, ids=[c[0] for c in CASES])
def test_a_file_of_another_kind_is_named_with_what_the_command_expects(files, tmp_path, line,
                                                                       kind, expects):
    args = line.format(d=tmp_path, **{k: str(v) for k, v in files.items()}).split()
    code, err = _run(*args)
    assert code == 1
    assert len(err) == 1 and err[0].startswith("error: "), err
    given = files[_wrong_file(line)]
    assert err[0].startswith(f"error: {given} is {KINDS[kind][0]} ("), err[0]
    assert expects in err[0], err[0]
    assert "this command" not in err[0]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["solve", "report", "solve --method ml"])
def test_a_short_session_says_so_without_naming_an_option_not_given(files, tmp_path, command):
    extra = ["-o", tmp_path / "r.html"] if command == "report" else []
    code, err = _run(*command.split(), files["short"], *extra)
    assert code == 1 and len(err) == 1, err
    assert err[0] == f"error: {files['short']}: 2 usable poses; a solve needs at least 3"


def test_a_short_train_set_still_names_train(files):
    code, err = _run("solve", files["session"], "--train", 2)
    assert code == 1 and err == ["error: --train 2: need at least 3 poses to solve"]


def test_selfcal_simulate_names_the_seed_option():
    code, err = _run("selfcal", "simulate", "--seed", "-1")
    assert code == 2 or code == 1
    assert len(err) == 1 and "'--seed'" in err[0] and "-1" in err[0], err
