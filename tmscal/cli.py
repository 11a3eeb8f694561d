"""The ``tmscal`` command line (click). Thin: parses, calls library functions, prints.

Every expected failure (bad input, device error, safety refusal) prints one line
``error: …`` naming the problem and exits non-zero; no tracebacks.
"""

from __future__ import annotations

import functools
import json
import logging
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click
import numpy as np

from . import __version__
from .errors import TmscalError

log = logging.getLogger("tmscal")

EXIT_ERROR = 1
EXIT_INTERRUPTED = 130


def _fail(msg: str, code: int = EXIT_ERROR) -> None:
    click.echo(f"error: {msg}", err=True)
    sys.exit(code)


def handle_errors(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Turn tmscal's typed errors (and OS errors) into one ``error:`` line and exit 1."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except TmscalError as e:
            _fail(str(e))
        except OSError as e:
            where = f"{e.filename}: " if getattr(e, "filename", None) else ""
            _fail(f"{where}{e.strerror or e}")

    return wrapper


def _write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` only once it is complete (temp file + rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _print_json(obj: Any) -> None:
    click.echo(json.dumps(obj, default=_json_default))


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="tmscal")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
def main(verbose: int) -> None:
    """tmscal: calibrate a robotized, navigated TMS rig.

    A robot (base ← flange = A) holds a coil; a tracker sees a marker on the coil
    (tracker ← marker = B) and a probe at its centre (tracker ← probe = C). tmscal solves
    X = flange ← marker, Y = flange ← probe (the coil calibration) and Z = base ← tracker
    from A X = Z B and A Y = Z C. All lengths are mm, angles degrees.

    \b
    Typical use:
      tmscal demo                         the whole job on the built-in mock rig
      tmscal simulate -o sim.jsonl        a simulated session (seed 000's protocol)
      tmscal solve sim.jsonl              QR36 calibration with held-out errors
      tmscal study sim.jsonl --plot f.png seed 000's Tables 1/3 and Figure 3
    """
    level = logging.WARNING if verbose == 0 else logging.INFO if verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")


# --- simulate -------------------------------------------------------------------------------

@main.command()
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Session file to write (JSON Lines).")
@click.option("--poses", type=click.IntRange(1, 100000), default=500, show_default=True,
              help="Number of robot poses.")
@click.option("--plan", type=click.Choice(["eq14", "random"]), default="eq14",
              show_default=True,
              help="eq14: seed 000's experiment plan (±100 mm, ±10° around P0); random: fully "
                   "random robot poses (seed 000's simulation).")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option("--samples", type=click.IntRange(1, 10000), default=1, show_default=True,
              help="Tracker observations averaged per pose.")
@click.option("--fiducial-sigma", type=click.FloatRange(0), default=0.05, show_default=True,
              help="Tracker fiducial noise σ per coordinate, mm.")
@click.option("--robot-rot-sigma", type=click.FloatRange(0), default=0.05, show_default=True,
              help="Robot rotation noise σ, degrees.")
@click.option("--robot-trans-sigma", type=click.FloatRange(0), default=0.05,
              show_default=True, help="Robot translation noise σ per axis, mm.")
@click.option("--radius", type=click.FloatRange(0), default=None,
              help="Translation range ±mm per axis (default 100 for eq14, 500 for random).")
@click.option("--rotation", type=click.FloatRange(0), default=10.0, show_default=True,
              help="eq14 rotation range ±degrees per axis.")
@click.option("--marker-only", is_flag=True, help="Simulate the marker only (no probe).")
@click.option("--force", is_flag=True, help="Overwrite an existing output file.")
@handle_errors
def simulate(output: Path, poses: int, plan: str, seed: int, samples: int,
             fiducial_sigma: float, robot_rot_sigma: float, robot_trans_sigma: float,
             radius: float | None, rotation: float, marker_only: bool, force: bool) -> None:
    """Write a simulated session (seed 000's protocol); the header carries the truth."""
    from .session import make_header, records_from_arrays, write_session
    from .sim import Noise
    from .sim import simulate as run_sim

    rng = np.random.default_rng(seed)
    noise = Noise(fiducial_sigma, robot_rot_sigma, robot_trans_sigma)
    truth, d = run_sim(poses, rng, plan=plan, noise=noise, samples=samples,
                       with_probe=not marker_only, radius_mm=radius, rotation_deg=rotation)
    bodies = ["marker"] if marker_only else ["marker", "probe"]
    header = make_header(
        bodies, truth={"X": truth.X, "Y": truth.Y, "Z": truth.Z},
        config={"simulate": {"poses": poses, "plan": plan, "seed": seed, "samples": samples,
                             "fiducial_sigma_mm": fiducial_sigma,
                             "robot_rot_sigma_deg": robot_rot_sigma,
                             "robot_trans_sigma_mm": robot_trans_sigma,
                             "radius_mm": radius, "rotation_deg": rotation}},
        devices={"robot": {"driver": "sim"}, "tracker": {"driver": "sim"}})
    recs = records_from_arrays(d["A"], d["marker"], d.get("probe"), d["commanded"], samples)
    write_session(output, header, recs, overwrite=force)
    click.echo(f"wrote {output}: {poses} poses ({plan} plan, seed {seed}), bodies "
               f"{', '.join(bodies)}, truth in the header")


# --- solve ----------------------------------------------------------------------------------

@main.command()
@click.argument("session_file", type=click.Path(path_type=Path))
@click.option("--method", type=click.Choice(["qr36", "qr24"]), default="qr36",
              show_default=True, help="qr36: X, Y, Z jointly; qr24: each body on its own.")
@click.option("--train", type=int, default=None,
              help="Solve on poses [0, N) and report errors on the rest (default: all poses, "
                   "errors in-sample).")
@click.option("--orthonormal", is_flag=True,
              help="Apply the orthonormal matrices (rotations projected, translations "
                   "re-solved) instead of the raw non-orthogonal ones (the paper's way).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the calibration YAML here.")
@handle_errors
def solve(session_file: Path, method: str, train: int | None, orthonormal: bool,
          as_json: bool, output: Path | None) -> None:
    """Solve a session for X, Y, Z and report the errors (seed 000's metrics)."""
    from .report.evaluate import solve_session
    from .report.text import calibration_yaml, format_result
    from .session import read_session, sha256_of

    session = read_session(session_file)
    if session.torn_tail:
        click.echo(f"warning: {session_file}: torn last line ignored", err=True)
    _, res = solve_session(session, method=method, train=train, orthonormal=orthonormal)
    if output is not None:
        _write_atomic(output, calibration_yaml(res, str(session_file), sha256_of(session_file)))
    if as_json:
        _print_json(res)
    else:
        click.echo(format_result(res))
        if output is not None:
            click.echo(f"\nwrote {output}")


# --- study ----------------------------------------------------------------------------------

@main.command()
@click.argument("session_file", type=click.Path(path_type=Path))
@click.option("--methods", default="qr24,qr36", show_default=True,
              help="Comma-separated methods to compare.")
@click.option("--n-max", type=click.IntRange(5), default=250, show_default=True,
              help="Largest training set; poses from n-max on are the test set.")
@click.option("--orthonormal", is_flag=True, help="Apply orthonormal matrices.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write seed 000's Figure 3 (error against n) as a PNG.")
@handle_errors
def study(session_file: Path, methods: str, n_max: int, orthonormal: bool, as_json: bool,
          plot: Path | None) -> None:
    """Convergence study: seed 000's Tables 1 and 3 and Figure 3 for a session."""
    from tqdm import tqdm

    from .calib import METHODS
    from .errors import CalibrationError
    from .report.evaluate import study_session
    from .report.text import format_study, plot_study
    from .session import read_session

    ms = [m.strip().lower() for m in methods.split(",") if m.strip()]
    bad = [m for m in ms if m not in METHODS]
    if not ms or bad:
        raise CalibrationError(f"--methods: unknown method {bad[0] if bad else '(none)'}; "
                               f"known: {', '.join(METHODS)}")
    session = read_session(session_file)
    total = len(ms) * max(0, n_max - 4)
    with tqdm(total=total, desc="solving", unit="solve", disable=None, file=sys.stderr,
              leave=False) as bar:
        res = study_session(session, ms, n_max=n_max, orthonormal=orthonormal,
                            progress=bar.update)
    if plot is not None:
        try:
            plot_study(res, str(plot), title=f"{session_file.name}: hold-out error on "
                                             f"{res['n_test']} poses")
        except ImportError:
            raise CalibrationError("--plot needs matplotlib: pip install 'tmscal[plot]'") \
                from None
    if as_json:
        _print_json(res)
    else:
        click.echo(format_study(res))
        if plot is not None:
            click.echo(f"\nwrote {plot}")


# --- demo -----------------------------------------------------------------------------------

@main.command()
@click.option("--poses", type=click.IntRange(3), default=500, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--json", "as_json", is_flag=True, help="Print the solve result as JSON.")
@handle_errors
def demo(poses: int, seed: int, as_json: bool) -> None:
    """Simulate a rig, solve it with QR36 and print the result against the truth."""
    from .report.evaluate import solve_session
    from .report.text import format_result
    from .session import Session, make_header, records_from_arrays
    from .sim import simulate as run_sim

    truth, d = run_sim(poses, np.random.default_rng(seed), plan="eq14", samples=1)
    header = make_header(["marker", "probe"], truth={"X": truth.X, "Y": truth.Y, "Z": truth.Z})
    s = Session(header, records_from_arrays(d["A"], d["marker"], d["probe"], d["commanded"]))
    _, res = solve_session(s, "qr36", train=poses // 2 if poses >= 6 else None)
    if as_json:
        _print_json(res)
    else:
        click.echo(format_result(res))


if __name__ == "__main__":  # pragma: no cover
    main()
