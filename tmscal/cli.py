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


def _plot(fn: Callable[..., None], *args: Any, **kwargs: Any) -> None:
    """Call a report plotting function; a missing matplotlib is one clear error."""
    from .errors import CalibrationError
    try:
        fn(*args, **kwargs)
    except ImportError:
        raise CalibrationError("--plot needs matplotlib: pip install 'tmscal[plot]'") from None


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


# --- argument types and the one rule for output files -----------------------------------------

class _Finite(click.ParamType):
    """A finite float (NaN and ±∞ refused) in [lo, hi]; ``lo_open`` makes the lower bound
    exclusive (e.g. a speed must be > 0)."""

    name = "number"

    def __init__(self, lo: float | None = None, hi: float | None = None,
                 lo_open: bool = False) -> None:
        self.lo, self.hi, self.lo_open = lo, hi, lo_open

    def convert(self, value: Any, param: Any, ctx: Any) -> float:
        if isinstance(value, float):
            v = value
        else:
            try:
                v = float(value)
            except (TypeError, ValueError):
                self.fail(f"{value!r} is not a number", param, ctx)
        if not np.isfinite(v):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        if self.lo is not None and (v < self.lo or (self.lo_open and v == self.lo)):
            self.fail(f"{v:g} must be {'>' if self.lo_open else '≥'} {self.lo:g}", param, ctx)
        if self.hi is not None and v > self.hi:
            self.fail(f"{v:g} must be ≤ {self.hi:g}", param, ctx)
        return v


class _InputFile(click.ParamType):
    """An existing regular file to read (a directory, FIFO or device is refused at once, so
    that a command never hangs reading one)."""

    name = "file"

    def convert(self, value: Any, param: Any, ctx: Any) -> Path:
        import stat

        path = Path(value)
        try:
            mode = path.stat().st_mode
        except OSError as e:
            self.fail(f"{path}: {e.strerror or e}", param, ctx)
        if not stat.S_ISREG(mode):
            kind = ("a directory" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode)
                    else "not a regular file")
            self.fail(f"{path}: is {kind}; expected a file", param, ctx)
        return path


INPUT_FILE = _InputFile()


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_outputs(outputs: dict[str, Path | None], inputs: list[Path], force: bool) -> None:
    """The one rule for every file a command writes (``-o``, ``--plot``, ``--report``): an
    existing file is refused unless ``--force``; an input of the command is never written
    over, even with ``--force``; two outputs may not be the same file. Raises
    ``click.BadParameter`` naming the option."""
    seen: dict[Path, str] = {}
    for opt, out in outputs.items():
        if out is None:
            continue
        for inp in inputs:
            if _same_file(out, inp) or out.resolve() == inp.resolve():
                raise click.BadParameter(f"{out} is an input of this command; it is never "
                                         "written over (choose another file)", param_hint=opt)
        key = out.resolve()
        if key in seen:
            raise click.BadParameter(f"{out} is also the {seen[key]} file", param_hint=opt)
        seen[key] = opt
        if out.is_dir():
            raise click.BadParameter(f"{out} is a directory", param_hint=opt)
        if out.exists() and not force:
            raise click.BadParameter(f"{out} already exists; add --force to overwrite it",
                                     param_hint=opt)


def _read_session(path: Path, strict: bool) -> Any:
    """Read a session for a command; what the reader skipped is said in one warning line
    (``_warn_damage``) instead of one log line per damaged line (unless -v)."""
    from .session import read_session

    logger = logging.getLogger("tmscal.session")
    level = logger.level
    if not log.isEnabledFor(logging.INFO):
        logger.setLevel(logging.ERROR)
    try:
        session = read_session(path, strict=strict)
    finally:
        logger.setLevel(level)
    _warn_damage(session)
    return session


def _warn_damage(session: Any) -> None:
    """Say on stderr what the reader skipped: a torn last line, damaged middle lines."""
    if session.torn_tail:
        click.echo(f"warning: {session.path}: torn last line ignored (an interrupted write)",
                   err=True)
    summary = session.damage_summary(limit=3)
    if summary:
        click.echo(f"warning: {session.path}: {summary}", err=True)


FORCE_HELP = "Overwrite existing output files (never an input file)."
STRICT_HELP = ("Refuse a session with a damaged line (default: skip it with a warning naming "
               "the line).")


class _OneLineErrors(click.Group):
    """The command group: a usage error (bad option, missing argument, bad value) prints one
    line ``error: …`` naming the option, then exits 2, as tmscal's own errors print one line
    and exit 1."""

    def main(self, *args: Any, **kwargs: Any) -> Any:  # type: ignore[override]
        kwargs["standalone_mode"] = False
        try:
            rv = super().main(*args, **kwargs)
        except click.exceptions.Abort:
            click.echo("aborted", err=True)
            sys.exit(EXIT_ERROR)
        except click.ClickException as e:
            cmd = getattr(getattr(e, "ctx", None), "command_path", None) or "tmscal"
            click.echo(f"error: {e.format_message()} (see: {cmd} --help)", err=True)
            sys.exit(e.exit_code)
        if isinstance(rv, int) and not isinstance(rv, bool):
            sys.exit(rv)  # click's Exit (e.g. after --help) returns its code here
        sys.exit(0)


@click.group(cls=_OneLineErrors, context_settings={"help_option_names": ["-h", "--help"]})
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
      tmscal demo                          the whole job on the built-in mock rig
      tmscal simulate -o sim.jsonl         a simulated session (Wang et al. 2018)
      tmscal solve sim.jsonl --train 250   QR36 on 250 poses, errors on the rest
      tmscal study sim.jsonl --plot f.png  convergence: error against the pose count
    \b
    At the rig (or against `tmscal mock CONFIG`):
      tmscal track CONFIG                  live tool poses: are the tools right?
      tmscal robot CONFIG                  robot identity and flange pose
      tmscal acquire CONFIG -o s.jsonl     record a session (--dry-run first)
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
              help="eq14: the experiment plan of Wang et al. 2018 (their Eq. 14: ±100 mm, "
                   "±10° around P0); random: fully random robot poses (their simulation).")
@click.option("--seed", type=click.IntRange(0), default=0, show_default=True,
              help="Random seed (≥ 0).")
@click.option("--samples", type=click.IntRange(1, 10000), default=1, show_default=True,
              help="Tracker observations averaged per pose.")
@click.option("--fiducial-sigma", type=_Finite(0, 100), default=0.05, show_default=True,
              help="Tracker fiducial noise σ per coordinate, mm.")
@click.option("--robot-rot-sigma", type=_Finite(0, 90), default=0.05, show_default=True,
              help="Robot rotation noise σ, degrees.")
@click.option("--robot-trans-sigma", type=_Finite(0, 100), default=0.05,
              show_default=True, help="Robot translation noise σ per axis, mm.")
@click.option("--radius", type=_Finite(0, 1e5), default=None,
              help="Translation range ±mm per axis (default 100 for eq14, 500 for random).")
@click.option("--rotation", type=_Finite(0, 180), default=10.0, show_default=True,
              help="eq14 rotation range ±degrees per axis.")
@click.option("--marker-only", is_flag=True, help="Simulate the marker only (no probe).")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@handle_errors
def simulate(output: Path, poses: int, plan: str, seed: int, samples: int,
             fiducial_sigma: float, robot_rot_sigma: float, robot_trans_sigma: float,
             radius: float | None, rotation: float, marker_only: bool, force: bool) -> None:
    """Write a simulated session (the simulation of Wang et al. 2018, docs/methods.md); the
    header carries the truth."""
    from .session import make_header, records_from_arrays, write_session
    from .sim import Noise
    from .sim import simulate as run_sim

    check_outputs({"--output": output}, [], force)
    if force and output.exists():
        output.unlink()
    rng = np.random.default_rng(seed)
    noise = Noise(fiducial_sigma, robot_rot_sigma, robot_trans_sigma)
    truth, d = run_sim(poses, rng, plan=plan, noise=noise, samples=samples,
                       with_probe=not marker_only, radius_mm=radius, rotation_deg=rotation)
    bodies = ["marker"] if marker_only else ["marker", "probe"]
    header = make_header(
        bodies, truth=truth.as_dict(),
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
@click.argument("session_file", type=INPUT_FILE)
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
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write a PNG of the per-pose errors (spot outlier poses).")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@click.option("--strict", is_flag=True, help=STRICT_HELP)
@handle_errors
def solve(session_file: Path, method: str, train: int | None, orthonormal: bool,
          as_json: bool, output: Path | None, plot: Path | None, force: bool,
          strict: bool) -> None:
    """Solve a session for X, Y, Z and report the errors (the metrics of Wang et al. 2018;
    docs/methods.md)."""
    from .report.evaluate import pose_residuals, solve_session
    from .report.text import calibration_yaml, format_result, plot_residuals
    from .session import sha256_of

    check_outputs({"--output": output, "--plot": plot}, [session_file], force)
    session = _read_session(session_file, strict)
    cal, res = solve_session(session, method=method, train=train, orthonormal=orthonormal)
    if output is not None:
        _write_atomic(output, calibration_yaml(res, str(session_file), sha256_of(session_file)))
    if plot is not None:
        _plot(plot_residuals, pose_residuals(session, cal), res["n_solve"], str(plot),
              f"{session_file.name}: {res['method']} per-pose errors")
    if as_json:
        _print_json(res)
    else:
        click.echo(format_result(res))
        for f in (output, plot):
            if f is not None:
                click.echo(f"\nwrote {f}")


# --- study ----------------------------------------------------------------------------------

@main.command()
@click.argument("session_file", type=INPUT_FILE)
@click.option("--methods", default="qr24,qr36", show_default=True,
              help="Comma-separated methods to compare.")
@click.option("--n-max", type=click.IntRange(5), default=250, show_default=True,
              help="Largest training set; poses from n-max on are the test set.")
@click.option("--orthonormal", is_flag=True, help="Apply orthonormal matrices.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the error against the number of poses as a PNG (as Figure 3 of "
                   "Wang et al. 2018).")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@click.option("--strict", is_flag=True, help=STRICT_HELP)
@handle_errors
def study(session_file: Path, methods: str, n_max: int, orthonormal: bool, as_json: bool,
          plot: Path | None, force: bool, strict: bool) -> None:
    """Convergence study of a session: errors against the number of poses, with the statistics
    and thresholds of Wang et al. 2018 (their Tables 1 and 3, Figure 3; docs/methods.md)."""
    from tqdm import tqdm

    from .calib import METHODS
    from .errors import CalibrationError
    from .report.evaluate import study_session
    from .report.text import format_study, plot_study

    ms = [m.strip().lower() for m in methods.split(",") if m.strip()]
    bad = [m for m in ms if m not in METHODS]
    if not ms or bad:
        raise CalibrationError(f"--methods: unknown method {bad[0] if bad else '(none)'}; "
                               f"known: {', '.join(METHODS)}")
    check_outputs({"--plot": plot}, [session_file], force)
    session = _read_session(session_file, strict)
    total = len(ms) * max(0, n_max - 4)
    with tqdm(total=total, desc="solving", unit="solve", disable=None, file=sys.stderr,
              leave=False) as bar:
        res = study_session(session, ms, n_max=n_max, orthonormal=orthonormal,
                            progress=bar.update)
    if plot is not None:
        _plot(plot_study, res, str(plot),
              title=f"{session_file.name}: hold-out error on {res['n_test']} poses")
    if as_json:
        _print_json(res)
    else:
        click.echo(format_study(res))
        if plot is not None:
            click.echo(f"\nwrote {plot}")


# --- rig commands: mock, track, robot, acquire, demo ------------------------------------------

def _default_demo_config() -> Path:
    return Path(__file__).resolve().parent.parent / "configs" / "mock-ur-polaris.yaml"


def _matrix_text(T: np.ndarray) -> str:
    from .report.text import format_matrix
    return format_matrix(T)


def _pose_line(T: np.ndarray) -> str:
    from .geometry import denso_p_from_matrix
    p = denso_p_from_matrix(T)
    return (f"x {p[0]:9.2f}  y {p[1]:9.2f}  z {p[2]:9.2f} mm   "
            f"rx {p[3]:8.3f}  ry {p[4]:8.3f}  rz {p[5]:8.3f} deg")


class _StopFlag:
    """First SIGINT/SIGTERM sets the flag (finish the pose in flight); a second SIGINT raises
    KeyboardInterrupt."""

    def __init__(self) -> None:
        self.set = False

    def __call__(self) -> bool:
        return self.set

    def install(self) -> None:
        import signal

        def handler(signum: int, frame: Any) -> None:
            if self.set and signum == signal.SIGINT:
                raise KeyboardInterrupt
            self.set = True
            click.echo("\nstopping after the pose in flight (Ctrl-C again to abort now)",
                       err=True)

        signal.signal(signal.SIGINT, handler)
        signal.signal(signal.SIGTERM, handler)


@main.command()
@click.argument("config", type=INPUT_FILE)
@click.option("--transport", type=click.Choice(["config", "pty", "tcp"]), default="config",
              show_default=True,
              help="Tracker transport: config = TCP on the config's socket:// port (else a "
                   "pty); pty = a new /dev/pts; tcp = an ephemeral loopback port.")
@click.option("--json", "as_json", is_flag=True,
              help='Print the endpoints as one JSON object on the first line, e.g. '
                   '{"tracker": "/dev/pts/7", "robot": "127.0.0.2"}.')
@handle_errors
def mock(config: Path, transport: str, as_json: bool) -> None:
    """Serve the mock devices of a rig config (one shared sim rig) until Ctrl-C / SIGTERM."""
    import signal
    import threading

    from .config import load_config
    from .mocks.rig import start_mock_rig

    cfg = load_config(config)
    done = threading.Event()
    signal.signal(signal.SIGINT, lambda *a: done.set())
    signal.signal(signal.SIGTERM, lambda *a: done.set())
    with start_mock_rig(cfg, tracker_transport=transport) as mr:
        if as_json:
            click.echo(json.dumps(mr.endpoints), nl=True)
        else:
            for k, v in mr.endpoints.items():
                click.echo(f"{k:<8} {v}")
            click.echo("serving; Ctrl-C to stop")
        sys.stdout.flush()
        while not done.wait(0.2):
            pass


@main.command()
@click.argument("config", type=INPUT_FILE)
@click.option("--port", "port", default=None,
              help="Tracker port (overrides the config): /dev/ttyUSB0, a pty, socket://…")
@click.option("--frames", type=click.IntRange(1), default=None,
              help="Stop after this many distinct frames (default: until Ctrl-C).")
@handle_errors
def track(config: Path, port: str | None, frames: int | None) -> None:
    """Connect to the tracker, list the tools and print live poses, quality and flags."""
    from .acquisition.devices import make_tracker
    from .config import load_config
    from .drivers.ndi.tracker import iter_frames

    cfg = load_config(config)
    with make_tracker(cfg, port) as tr:
        ident = tr.identity()
        click.echo("tracker: " + ", ".join(f"{k} {v}" for k, v in ident.items() if v))
        handles = getattr(tr, "handles", {})
        for name in tr.tools:
            h = handles.get(name)
            click.echo(f"  tool {name:<8} handle {h if h is not None else '?'}")
        try:
            for fr in iter_frames(tr, frames):
                parts = [f"frame {fr.frame:>8}"]
                for name, st in fr.tools.items():
                    if st.pose is None:
                        parts.append(f"{name}: MISSING")
                        continue
                    t = st.pose[:3, 3]
                    flags = [f for f, on in (("out-of-volume", st.out_of_volume),
                                             ("partly-out", st.partially_out_of_volume))
                             if on]
                    err = f" err {st.error_mm:.3f}" if st.error_mm is not None else ""
                    parts.append(f"{name}: ({t[0]:8.2f} {t[1]:8.2f} {t[2]:9.2f}) mm{err}"
                                 + (" " + ",".join(flags) if flags else ""))
                click.echo("  ".join(parts))
        except KeyboardInterrupt:
            pass


@main.command()
@click.argument("config", type=INPUT_FILE)
@click.option("--host", default=None, help="Robot address (overrides the config).")
@click.option("--move-to", "move_to", default=None, metavar="X,Y,Z,RX,RY,RZ",
              help="Jog the flange to this pose (mm, deg; R = Rz·Ry·Rx, base frame) after a "
                   "confirmation. The config's safety envelope applies around the current "
                   "pose.")
@click.option("--speed", type=_Finite(0, lo_open=True), default=None,
              help="Jog speed, mm/s (capped by safety.max_speed_mm_s).")
@click.option("--yes", is_flag=True, help="Do not ask for confirmation.")
@handle_errors
def robot(config: Path, host: str | None, move_to: str | None, speed: float | None,
          yes: bool) -> None:
    """Connect to the robot, report its identity and flange pose; optionally jog."""
    from .acquisition.devices import envelope_for, make_robot
    from .config import load_config
    from .geometry import matrix_from_denso_p

    target = None
    if move_to is not None:  # parsed before anything connects
        try:
            vals = [float(v) for v in move_to.split(",")]
            if len(vals) != 6 or not np.isfinite(vals).all():
                raise ValueError
        except ValueError:
            raise click.BadParameter(f"{move_to!r}: expected 6 finite numbers "
                                     "X,Y,Z,RX,RY,RZ (mm, deg)", param_hint="--move-to") \
                from None
        target = matrix_from_denso_p(vals)
    cfg = load_config(config)
    with make_robot(cfg, envelope_for(cfg, None), host) as rb:
        click.echo("robot: " + ", ".join(f"{k} {v}" for k, v in rb.identity().items() if v))
        here = rb.flange_pose()
        click.echo("flange (base ← flange): " + _pose_line(here))
        click.echo(_matrix_text(here))
        if target is None:
            return
        rb.envelope = envelope_for(cfg, here)
        rb.envelope.check_pose(target, "--move-to target")
        v = speed if speed is not None else rb.speed_mm_s
        if not yes and not click.confirm(f"move the flange to {_pose_line(target)} at "
                                         f"{v} mm/s?", default=False):
            click.echo("not moved")
            return
        rb.move_to(target, v)
        click.echo("arrived: " + _pose_line(rb.flange_pose()))


@main.command()
@click.argument("config", type=INPUT_FILE)
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Session file (JSON Lines) to write or, with --resume, to continue.")
@click.option("--resume", is_flag=True,
              help="Continue an interrupted session: same plan, same P0, done poses skipped.")
@click.option("--poses", type=click.IntRange(1, 100000), default=None,
              help="Number of poses (overrides plan.poses).")
@click.option("--samples", type=click.IntRange(1), default=None,
              help="Distinct tracker frames averaged per pose (overrides sampling.samples).")
@click.option("--dry-run", is_flag=True,
              help="Print the plan's extent and estimated duration; move nothing.")
@click.option("--tracker-port", default=None, help="Tracker port (overrides the config).")
@click.option("--robot-host", default=None, help="Robot address (overrides the config).")
@handle_errors
def acquire(config: Path, output: Path, resume: bool, poses: int | None,
            samples: int | None, dry_run: bool, tracker_port: str | None,
            robot_host: str | None) -> None:
    """Move the robot through the plan and record a session (A, B, C at every pose).

    Each pose: move, settle, average N distinct tracker frames (and the robot pose read
    alongside), append one fsynced line. Ctrl-C finishes the pose in flight and leaves a
    resumable session; device faults are retried with a reconnect.
    """
    from tqdm import tqdm

    from .acquisition.run import AcquisitionStopped
    from .acquisition.run import acquire as run_acquire
    from .config import load_config

    if _same_file(output, config):  # an existing session is the run's to resume, never this
        raise click.BadParameter(f"{output} is the config file; it is never written over",
                                 param_hint="--output")
    cfg = load_config(config)
    if dry_run:
        _dry_run(cfg, poses, samples, robot_host)
        return
    stop = _StopFlag()
    stop.install()
    bar: Any = None
    skipped = [0]

    def on_start(done: int, total: int) -> None:
        nonlocal bar
        bar = tqdm(total=total, initial=done, desc="poses", unit="pose", file=sys.stderr,
                   dynamic_ncols=True)

    def on_pose(done: int, total: int, rec: Any) -> None:
        post = {}
        for b in ("marker", "probe"):
            sp = rec.spread.get(b)
            if sp:
                post[b] = f"{sp['trans_mm']:.3f}mm/{sp['rot_deg']:.3f}°"
        if rec.skipped:
            skipped[0] += 1
        if skipped[0]:
            post["skipped"] = str(skipped[0])
        bar.set_postfix(post, refresh=False)
        bar.update(1)

    try:
        res = run_acquire(cfg, output, resume=resume, poses=poses, samples=samples,
                          tracker_port=tracker_port, robot_host=robot_host, on_pose=on_pose,
                          on_start=on_start, should_stop=stop)
    except AcquisitionStopped as e:
        if bar is not None:
            bar.close()
        _fail(f"acquisition stopped: {e}")
        return
    finally:
        if bar is not None:
            bar.close()
    _acquire_summary(res, config, output, tracker_port, robot_host)
    if res.stopped:
        sys.exit(EXIT_INTERRUPTED)


def _acquire_summary(res: Any, config: Path, output: Path, tracker_port: str | None = None,
                     robot_host: str | None = None) -> None:
    from .acquisition.run import resume_command

    state = "stopped early (resumable)" if res.stopped else "complete"
    for note in res.notes:
        click.echo(f"note: {note}")
    click.echo(f"session {output}: {state}; {res.recorded} poses recorded, {res.skipped} "
               f"skipped, of {res.total} planned; {res.new_poses} new in "
               f"{res.elapsed_s:.1f} s; device faults recovered: {res.faults}")
    if res.stopped:
        click.echo("resume with: " + resume_command(config, output, tracker_port, robot_host))
    click.echo(f"next: tmscal solve {output} --method qr36 -o {output.with_suffix('.yaml')}")


def _dry_run(cfg: Any, poses: int | None, samples: int | None, robot_host: str | None) -> None:
    from .acquisition.dryrun import dry_run
    from .errors import SafetyError

    d = dry_run(cfg, poses, samples, robot_host)
    s = d.summary
    click.echo(f"plan {d.spec.kind}: {d.spec.n} poses, seed {d.spec.seed}, around P0 "
               f"({d.p0_source}):")
    click.echo("  P0 " + _pose_line(d.spec.p0))
    click.echo(f"  offsets from P0: x {s['x_range_mm'][0]:.1f}…{s['x_range_mm'][1]:.1f}, "
               f"y {s['y_range_mm'][0]:.1f}…{s['y_range_mm'][1]:.1f}, "
               f"z {s['z_range_mm'][0]:.1f}…{s['z_range_mm'][1]:.1f} mm; "
               f"max {s['offset_max_mm']:.1f} mm")
    click.echo(f"  rotation from P0: max {s['rotation_max_deg']:.2f} deg")
    click.echo(f"  {'in the robot base frame (mm)':<32} {'x':^16}{'y':^16}{'z':^16}")
    for label, key in (("workspace box (safety)", "box"), ("flange over the plan", "flange"),
                       ("tool points over the plan", "tool")):
        lo, hi = s[f"{key}_min_mm"], s[f"{key}_max_mm"]
        if lo is not None:
            cells = "".join(f"{a:8.1f}…{b:<7.1f}" for a, b in zip(lo, hi))
            click.echo(f"    {label:<30} {cells}")
    if s["tool_min_mm"] is None:
        click.echo("    (no safety.tool_points_mm: the box bounds the flange only)")
    click.echo(f"  estimated duration: {s['duration_s'] / 60:.1f} min (travel "
               f"{s['travel_mm'] / 1000:.1f} m = {s['motion_s']:.0f} s at "
               f"{d.speed_mm_s:g} mm/s, sampling {s['sampling_s']:.0f} s)")
    if d.refusal is not None:
        raise SafetyError(d.refusal)
    click.echo("  safety envelope: every pose inside")


@main.command()
@click.option("--config", "config", type=INPUT_FILE, default=None,
              help="Mock rig config (default: configs/mock-ur-polaris.yaml).")
@click.option("--poses", type=click.IntRange(3, 100000), default=None,
              help="Override plan.poses.")
@click.option("--samples", type=click.IntRange(1), default=None,
              help="Override sampling.samples.")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Keep the session here (default: a temporary file).")
@click.option("--transport", type=click.Choice(["tcp", "pty"]), default="tcp",
              show_default=True,
              help="How the Polaris mock is reached: loopback TCP (socket://, as NDI's network "
                   "trackers) or a pty (as a serial port).")
@click.option("--json", "as_json", is_flag=True,
              help="Print the solve result (with the mock rig's truth) as one JSON object.")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@handle_errors
def demo(config: Path | None, poses: int | None, samples: int | None, output: Path | None,
         transport: str, as_json: bool, force: bool) -> None:
    """The whole job on the built-in mock rig: start the mock robot and Polaris, acquire
    through the real drivers and wire protocols, solve with QR36, compare with the truth."""
    from tqdm import tqdm

    from .acquisition.run import acquire as run_acquire
    from .config import load_config
    from .mocks.rig import build_sim_rig, spawn_mock_rig
    from .report.evaluate import solve_session
    from .report.text import format_result
    from .session import read_session

    cfg_path = config or _default_demo_config()
    check_outputs({"--output": output}, [cfg_path], force)
    if output is not None and force and output.exists():
        output.unlink()
    cfg = load_config(cfg_path)
    truth = build_sim_rig(cfg).truth  # the child builds the same rig from the same config
    tmp = None
    if output is None:
        tmp = tempfile.TemporaryDirectory(prefix="tmscal-demo-")
        output = Path(tmp.name) / "demo-session.jsonl"
    try:
        # the mocks run in a child process: ur_rtde holds the GIL while it waits for them
        with spawn_mock_rig(cfg_path, transport=transport) as mp:
            ep = mp.endpoints
            if not as_json:
                click.echo("mock rig: " + ", ".join(f"{k} {v}" for k, v in ep.items()))
            bar: Any = None

            def on_start(done: int, total: int) -> None:
                nonlocal bar
                bar = tqdm(total=total, initial=done, desc="acquiring", unit="pose",
                           file=sys.stderr, disable=None)

            host, _, port = ep["robot"].partition(":")
            res = run_acquire(cfg, output, poses=poses, samples=samples,
                              tracker_port=ep["tracker"], robot_host=host,
                              robot_port=int(port) if port else None,
                              on_start=on_start, on_pose=lambda d, t, r: bar.update(1))
            if bar is not None:
                bar.close()
        session = read_session(output)
        session.header["truth"] = truth.as_dict()
        _, result = solve_session(session, "qr36")
        if as_json:
            _print_json(result)
            return
        click.echo(f"acquired {res.recorded} poses ({res.skipped} skipped) in "
                   f"{res.elapsed_s:.1f} s through the wire protocols\n")
        click.echo(format_result(result))
        click.echo("\n  truth (the mock rig's):")
        for k, name in (("X", "flange_from_marker"), ("Y", "flange_from_probe"),
                        ("Z", "base_from_tracker")):
            click.echo(f"  {k} = {name}")
            click.echo(_matrix_text(np.asarray(getattr(truth, k))))
    finally:
        if tmp is not None:
            tmp.cleanup()


if __name__ == "__main__":  # pragma: no cover
    main()
