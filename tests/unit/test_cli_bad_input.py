"""The CLI's bad-input table: every command against missing files, directories, FIFOs,
existing outputs, inputs as outputs, wrong types, NaN and ∞, and sessions too small or all
skipped. Each case must print exactly one ``error:`` line on stderr (no traceback), exit
non-zero, and leave every file in the work folder as it was."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.session import PoseRecord, make_header, records_from_arrays, write_session

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """A folder with a good session, a 2-pose session, an all-skipped session, a FIFO, a
    directory, an existing output, and configs good and bad."""
    d = tmp_path_factory.mktemp("bad-input")
    r = CliRunner().invoke(main, ["simulate", "-o", str(d / "good.jsonl"), "--poses", "40"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["simulate", "-o", str(d / "two.jsonl"), "--poses", "2"])
    assert r.exit_code == 0, r.output
    eye = np.eye(4)
    write_session(d / "skipped.jsonl", make_header(["marker", "probe"]),
                  [PoseRecord(index=i, A=None, B=None, skipped="probe usable in 0 of 5 frames")
                   for i in range(6)])
    write_session(d / "flat.jsonl", make_header(["marker", "probe"]),
                  records_from_arrays(np.stack([eye] * 8), np.stack([eye] * 8),
                                      np.stack([eye] * 8)))
    os.mkfifo(d / "fifo")
    (d / "folder").mkdir()
    (d / "exists.yaml").write_text("keep me\n")
    (d / "exists.png").write_text("keep me\n")
    good = yaml.safe_load((REPO / "configs" / "mock-denso-polaris.yaml").read_text())
    good["tracker"]["tools"] = {k: str(REPO / "configs" / v)
                                for k, v in good["tracker"]["tools"].items()}
    (d / "good.yaml").write_text(yaml.safe_dump(good))
    nan_box = yaml.safe_load(yaml.safe_dump(good))
    nan_box["safety"]["workspace_min_mm"][0] = float("nan")
    (d / "nan-box.yaml").write_text(yaml.safe_dump(nan_box))
    no_safety = {k: v for k, v in good.items() if k != "safety"}
    (d / "no-safety.yaml").write_text(yaml.safe_dump(no_safety))
    spy = yaml.safe_load(yaml.safe_dump(good))
    spy["tracker"]["port"] = f"spy://{d / 'good.jsonl'}?file={d / 'victim.txt'}"
    (d / "victim.txt").write_text("keep me\n")
    (d / "spy.yaml").write_text(yaml.safe_dump(spy))
    (d / "broken.yaml").write_text("robot: [unclosed\n")
    (d / "cycle.yaml").write_text("robot: &a\n  driver: denso\n  options: {x: *a}\n")
    return d


def _snapshot(d: Path) -> dict[str, bytes | str]:
    out: dict[str, bytes | str] = {}
    for p in sorted(d.rglob("*")):
        if p.is_fifo():
            out[p.name] = "fifo"
        elif p.is_dir():
            out[p.name] = "dir"
        else:
            out[p.name] = p.read_bytes()
    return out


# (id, command line with {d} for the work folder, a word the error must contain)
CASES = [
    # simulate
    ("sim-existing", "simulate -o {d}/good.jsonl --poses 5", "already exists"),
    ("sim-dir", "simulate -o {d}/folder --poses 5", "folder"),
    ("sim-seed-neg", "simulate -o {d}/new.jsonl --seed -1", "--seed"),
    ("sim-radius-nan", "simulate -o {d}/new.jsonl --radius nan", "--radius"),
    ("sim-rotation-inf", "simulate -o {d}/new.jsonl --rotation inf", "--rotation"),
    ("sim-sigma-nan", "simulate -o {d}/new.jsonl --fiducial-sigma nan", "--fiducial-sigma"),
    ("sim-poses-word", "simulate -o {d}/new.jsonl --poses many", "--poses"),
    ("sim-poses-zero", "simulate -o {d}/new.jsonl --poses 0", "--poses"),
    # solve
    ("solve-missing", "solve {d}/none.jsonl", "none.jsonl"),
    ("solve-dir", "solve {d}/folder", "directory"),
    ("solve-fifo", "solve {d}/fifo", "FIFO"),
    ("solve-yaml-as-session", "solve {d}/good.yaml", "is a rig config"),
    ("solve-two-poses", "solve {d}/two.jsonl", "2 usable poses; a solve needs at least 3"),
    ("solve-all-skipped", "solve {d}/skipped.jsonl", "usable"),
    ("solve-flat", "solve {d}/flat.jsonl", "rotation"),
    ("solve-existing-out", "solve {d}/good.jsonl -o {d}/exists.yaml", "already exists"),
    ("solve-existing-plot", "solve {d}/good.jsonl --plot {d}/exists.png", "already exists"),
    ("solve-out-is-input", "solve {d}/good.jsonl -o {d}/good.jsonl --force", "input"),
    ("solve-plot-is-input", "solve {d}/good.jsonl --plot {d}/good.jsonl --force", "input"),
    ("solve-out-is-plot", "solve {d}/good.jsonl -o {d}/x.yaml --plot {d}/x.yaml", "also"),
    ("solve-bad-method", "solve {d}/good.jsonl --method qr99", "--method"),
    ("solve-train-word", "solve {d}/good.jsonl --train ten", "--train"),
    # study
    ("study-missing", "study {d}/none.jsonl", "none.jsonl"),
    ("study-fifo", "study {d}/fifo", "FIFO"),
    ("study-two-poses", "study {d}/two.jsonl", "poses"),
    ("study-all-skipped", "study {d}/skipped.jsonl --n-max 5", "usable"),
    ("study-degenerate", "study {d}/flat.jsonl --n-max 5 --methods qr24", "rotation"),
    ("study-plot-is-input", "study {d}/good.jsonl --n-max 10 --plot {d}/good.jsonl --force",
     "input"),
    ("study-existing-plot", "study {d}/good.jsonl --n-max 10 --plot {d}/exists.png",
     "already exists"),
    # the rig commands fail before any device opens
    ("acquire-missing-config", "acquire {d}/none.yaml -o {d}/s.jsonl", "none.yaml"),
    ("acquire-config-dir", "acquire {d}/folder -o {d}/s.jsonl", "directory"),
    ("acquire-config-fifo", "acquire {d}/fifo -o {d}/s.jsonl", "FIFO"),
    ("acquire-out-is-config", "acquire {d}/good.yaml -o {d}/good.yaml", "config"),
    ("acquire-existing-session", "acquire {d}/good.yaml -o {d}/good.jsonl", "--resume"),
    ("acquire-nan-box", "acquire {d}/nan-box.yaml -o {d}/s.jsonl", "workspace_min_mm"),
    ("acquire-no-safety", "acquire {d}/no-safety.yaml -o {d}/s.jsonl", "safety"),
    ("acquire-spy-port", "acquire {d}/spy.yaml -o {d}/s.jsonl", "tracker.port"),
    ("acquire-broken-yaml", "acquire {d}/broken.yaml -o {d}/s.jsonl", "line"),
    ("acquire-yaml-cycle", "acquire {d}/cycle.yaml -o {d}/s.jsonl", "cycle.yaml"),
    ("acquire-resume-missing", "acquire {d}/good.yaml -o {d}/none.jsonl --resume",
     "none.jsonl"),
    ("acquire-poses-huge", "acquire {d}/good.yaml -o {d}/s.jsonl --poses 1000000000",
     "--poses"),
    ("acquire-samples-zero", "acquire {d}/good.yaml -o {d}/s.jsonl --samples 0", "--samples"),
    ("track-spy-port", "track {d}/spy.yaml --frames 1", "tracker.port"),
    ("track-fifo", "track {d}/fifo", "FIFO"),
    ("robot-nan-box", "robot {d}/nan-box.yaml", "workspace_min_mm"),
    ("robot-speed-nan", "robot {d}/good.yaml --speed nan", "--speed"),
    ("robot-speed-neg", "robot {d}/good.yaml --speed -5", "--speed"),
    ("robot-move-to-words", "robot {d}/good.yaml --move-to 1,2,3", "--move-to"),
    ("robot-move-to-nan", "robot {d}/good.yaml --move-to 500,0,nan,180,0,0", "--move-to"),
    ("mock-missing", "mock {d}/none.yaml", "none.yaml"),
    ("mock-dir", "mock {d}/folder", "directory"),
    ("demo-config-fifo", "demo --config {d}/fifo", "FIFO"),
    ("demo-existing-out", "demo -o {d}/good.jsonl", "already exists"),
    ("demo-out-is-config", "demo --config {d}/good.yaml -o {d}/good.yaml --force", "input"),
    ("unknown-command", "calibrate {d}/good.jsonl", "calibrate"),
]


@pytest.mark.parametrize("case, line, word", CASES, ids=[c[0] for c in CASES])
def test_bad_input_gives_one_error_line_and_changes_nothing(work, case, line, word):
    before = _snapshot(work)
    args = line.format(d=work).split()
    r = CliRunner().invoke(main, args)
    assert r.exit_code not in (0, None), r.output
    assert "Traceback" not in r.output and r.exception is None or \
        isinstance(r.exception, SystemExit), repr(r.exception)
    err = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith("error: "), r.stderr
    assert word.lower() in err[0].lower(), err[0]
    assert _snapshot(work) == before


@pytest.mark.parametrize("library, cli", [
    ("s.jsonl: already exists; resume it (resume=True) or choose another file",
     "s.jsonl: already exists; resume it (--resume) or choose another file"),
    ("rig.yaml: name the arm's nominal model (arm=)", "rig.yaml: name the arm's nominal model "
     "(--arm)"),
    ("recorded for arm 'ur5e'; arm='vs060' was given; resume with",
     "recorded for arm 'ur5e'; --arm vs060 was given; resume with"),
    ("P0 is the calibration's, cal.yaml (origin=), not where the arm was left",
     "P0 is the calibration's, cal.yaml (--calib), not where the arm was left"),
    ("(plan.start: current); give origin=CAL to run around",
     "(plan.start: current); give --calib CAL to run around"),
    ("kinematics='estimate' needs joints", "--kinematics estimate needs joints"),
])
def test_library_messages_name_parameters_and_the_cli_words_them_as_its_options(library, cli):
    """The acquisition and solve layers name the arguments of their calls; the command line
    translates each to the option that sets it (cli.app.as_flags), and leaves the rest."""
    from tmscal.cli.app import as_flags

    assert "--" not in library
    assert as_flags(library) == cli
