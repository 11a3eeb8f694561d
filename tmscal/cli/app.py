"""The ``tmscal`` click group and what every command shares: the typed-error handler (one
``error: …`` line, exit 1), the argument types, the one rule for output files, session
reading, JSON output. The commands register themselves on ``main`` from their own modules
(:mod:`tmscal.cli` imports them).
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NoReturn

import click
import numpy as np

from .. import __version__
from ..errors import TmscalError
from ..session.jsonable import json_default

log = logging.getLogger("tmscal")

EXIT_ERROR = 1
#: a check that ran and failed (``solve --calib`` over its tolerance, ``selftest``): not an
#: error of tmscal's, a verdict (1 is an error, 2 a usage error)
EXIT_CHECK_FAILED = 3
EXIT_INTERRUPTED = 130
#: the reader of stdout went away (``tmscal robot | head``): 128 + SIGPIPE, the status a shell
#: reports for a program its pipe ended, so that ``set -o pipefail`` still sees that the
#: output was cut short, and nothing is printed
EXIT_BROKEN_PIPE = 141


def fail(msg: str, code: int = EXIT_ERROR) -> None:
    """Print ``error: msg`` on stderr and exit with ``code`` (1 by default)."""
    click.echo(f"error: {msg}", err=True)
    sys.exit(code)


def stdout_closed() -> NoReturn:
    """Exit quietly with ``EXIT_BROKEN_PIPE`` after a write to a closed pipe (stdout, or
    stderr piped with it): no message, since the reader is gone and wanted no more; both
    streams go to the null device first, so that the interpreter's flush at exit raises
    nothing either (Python's documentation on SIGPIPE: "Note on SIGPIPE")."""
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        for stream in (sys.stdout, sys.stderr):
            os.dup2(null, stream.fileno())
    except (OSError, ValueError, AttributeError):  # no file descriptor behind a stream
        pass
    sys.exit(EXIT_BROKEN_PIPE)


def handle_errors(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Turn tmscal's typed errors (and OS errors) into one ``error:`` line and exit 1; a
    write to a closed pipe (``tmscal robot | head``) exits quietly with
    ``EXIT_BROKEN_PIPE`` (:func:`stdout_closed`)."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except BrokenPipeError:
            stdout_closed()
        except TmscalError as e:
            fail(as_flags(_name_command(str(e))))
        except OSError as e:
            where = f"{e.filename}: " if getattr(e, "filename", None) else ""
            fail(f"{where}{e.strerror or e}")

    return wrapper


#: how a library message names the arguments of a library call (``tmscal.solving.solve``,
#: ``compare_arrays``), and the command-line options that set them
PARAMETER_FLAGS: list[tuple[str, str]] = [
    (r"\bkinematics='estimate'", "--kinematics estimate"),
    (r"\bkinematics=<an arm>", "--kinematics"),
    (r"\bmethod='([\w-]+)'", r"--method \1"),
    (r"\btrain=N\b", "--train"),
    (r"\btrain=(-?\d+)", r"--train \1"),
    (r"\bin_sample=True", "--in-sample"),
    (r"(?<![\w.-])arm='([\w-]+)' was given", r"--arm \1 was given"),
    (r"(?<![\w.-])arm=(?=\W|$)", "--arm"),
    (r"\bresume=True", "--resume"),
    (r"\borigin=CAL\b", "--calib CAL"),
    (r"\(origin=\)", "(--calib)"),
    (r"\blevel=(?=\W|$)", "--level"),
    (r"\btolerances=(?=\W|$)", "--tolerance-length/--tolerance-angle"),
    (r"\bfolds=(-?\d+)", r"--folds \1"),
    (r"\bns=(-?\d+)", r"--n \1"),
]


def as_flags(msg: str) -> str:
    """``msg`` (a library error) with the arguments it names worded as the options that set
    them (:data:`PARAMETER_FLAGS`: ``kinematics='estimate'`` → ``--kinematics estimate``,
    ``train=2`` → ``--train 2``)."""
    import re

    for pattern, flag in PARAMETER_FLAGS:
        msg = re.sub(pattern, flag, msg)
    return msg


def _name_command(msg: str) -> str:
    """``msg`` with the command running in place of the words a library message uses for it
    (``tmscal.filekind.THIS_COMMAND``: "… is a tmscal session; tmscal track expects a rig
    config …")."""
    from ..filekind import THIS_COMMAND

    ctx = click.get_current_context(silent=True)
    if ctx is None or THIS_COMMAND not in msg:
        return msg
    words = ["tmscal", *ctx.command_path.split()[1:]]  # the program's name, however invoked
    return msg.replace(THIS_COMMAND, " ".join(words), 1)


def write_atomic(path: Path, text: str, force: bool = False) -> None:
    """Write an output file whole or not at all, mode 0666 & ~umask, never over a file
    another tmscal process holds locked, over an existing one only with ``force``
    (``tmscal.session.outputs.write_output``; call ``check_outputs`` first)."""
    from ..session.outputs import write_output
    write_output(path, text, overwrite=force)


def run_plot(fn: Callable[..., None], *args: Any, **kwargs: Any) -> None:
    """Call a report plotting function; a missing matplotlib is one clear error."""
    from ..errors import MissingExtraError
    try:
        fn(*args, **kwargs)
    except ImportError as e:
        raise MissingExtraError("--plot", "plot", str(e)) from None


@contextlib.contextmanager
def output_files(outputs: dict[str, Path], force: bool) -> Iterator[dict[str, str]]:
    """Temporary paths (same folder and suffix) to write the output files ``outputs``
    {key: path} to, e.g. by matplotlib; once the block has written them all, each is put in
    place by the rule of ``write_atomic``; if it raises, none is."""
    from ..session.outputs import output_path

    with contextlib.ExitStack() as stack:
        yield {k: str(stack.enter_context(output_path(p, overwrite=force)))
               for k, p in outputs.items()}


def _json_default(o: Any) -> Any:
    """``json_default`` of the session's JSON types, and paths as strings."""
    return str(o) if isinstance(o, Path) else json_default(o)


def print_json(obj: Any) -> None:
    """Print ``obj`` as one line of JSON (numpy values and paths converted)."""
    click.echo(json.dumps(obj, default=_json_default))


# --- argument types and the one rule for output files -----------------------------------------

class Finite(click.ParamType):
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


def same_file(a: Path, b: Path) -> bool:
    """True when both paths exist and are the same file (links followed)."""
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_outputs(outputs: dict[str, Path | None], inputs: list[Path], force: bool) -> None:
    """The one rule for every file a command writes (``-o``, ``--plot``, ``--report``): an
    existing file is refused unless ``--force``; an input of the command is never written
    over, even with ``--force``; nor is a file another tmscal process holds locked (a
    session being recorded); two outputs may not be the same file. Raises
    ``click.BadParameter`` naming the option."""
    seen: dict[Path, str] = {}
    for opt, out in outputs.items():
        if out is None:
            continue
        for inp in inputs:
            if same_file(out, inp) or out.resolve() == inp.resolve():
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
        if out.exists():
            _check_not_locked(out, opt)


def _check_not_locked(out: Path, opt: str) -> None:
    """--force never replaces a file another tmscal process holds locked (a session being
    recorded): refused here, before any work, and again when the file is put in place."""
    from ..errors import SessionError
    from ..session.outputs import check_not_locked

    try:
        check_not_locked(out)
    except SessionError as e:
        raise click.BadParameter(str(e), param_hint=opt) from None


def read_session_file(path: Path, strict: bool) -> Any:
    """Read a session for a command; what the reader skipped is said in one warning line
    (``_warn_damage``) instead of one log line per damaged line (unless -v)."""
    from ..session import read_session

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


#: help of the options that override a device's address: each names its device (the one scheme
#: of every command; a server's own address, as stream's, is --host/--port)
TRACKER_PORT_HELP = ("Tracker address (overrides the config's): an NDI's device path or "
                     "socket://host:port; an OpenIGTLink source's host:port.")
ROBOT_HOST_HELP = "Robot address (overrides the config)."


def old_spelling(new: str | None, old: str | None, new_name: str, old_name: str
                 ) -> str | None:
    """The value of option ``new_name`` given either as itself or by its old, hidden
    spelling ``old_name`` (kept so that scripts keep working); both at once is refused."""
    if new is not None and old is not None:
        raise click.BadParameter(f"{old_name} is the old spelling of {new_name}; give one",
                                 param_hint=old_name)
    return new if new is not None else old


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
        try:  # what is still buffered, while a closed pipe can be told apart
            sys.stdout.flush()
        except BrokenPipeError:
            stdout_closed()
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
      tmscal compare sim.jsonl             every method side by side (error, time)
      tmscal report sim.jsonl -o r.html    one HTML page for the lab notebook
      tmscal export c.yaml --format itk    the calibration for Slicer, PLUS, ROS, InVesalius
      tmscal selfcal simulate              force-torque self-calibration study
    \b
    At the rig (or against `tmscal mock CONFIG`):
      tmscal track CONFIG                  live tool poses: are the tools right?
      tmscal robot CONFIG                  robot identity and flange pose
      tmscal acquire CONFIG -o s.jsonl --adaptive
                                           record a session until the predicted
                                           coil error reaches 0.05 mm (--dry-run first)
      tmscal selftest --rig CONFIG         the acceptance checks of the rig's devices
      tmscal solve s.jsonl --calib c.yaml --tolerance-mm 1
                                           the daily check of a stored calibration
      tmscal stream CONFIG --calib c.yaml  the live coil pose to 3D Slicer (OpenIGTLink)
      tmscal selfcal acquire CONFIG -o f.jsonl
                                           joints + wrist wrench for self-calibration
    """
    level = logging.WARNING if verbose == 0 else logging.INFO if verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
