"""Output files (issue 22, items 5, 7 and 10): ``--force`` never replaces a file another tmscal
process holds locked (a session being recorded), a session's header is on disk whole or not
at all, and every output is created with the umask's mode (tmscal.session.outputs)."""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import stat
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from click.testing import CliRunner

from tmscal.cli import main
from tmscal.errors import SessionError
from tmscal.session import SessionWriter, make_header, read_session, write_session
from tmscal.session import files as session_mod
from tmscal.session.outputs import output_path, write_output

from ..rigs import REPO, simulated
from .test_kinfile import selfcal_session

pytest.importorskip("matplotlib")

_TRUTH, _D = simulated(30)
LOCKED = "in use by another tmscal process"

#: a child process that holds a session the way a running acquisition does: resumed for
#: appending, under the writer's lock, until its stdin closes
_HOLDER = """
import sys
from tmscal.session import SessionWriter
w = SessionWriter.resume(sys.argv[1])
print("locked", flush=True)
sys.stdin.read()
w.close()
"""


def _cli(*args: object) -> object:
    return CliRunner().invoke(main, [str(a) for a in args])


def _ok(*args: object) -> None:
    r = _cli(*args)
    assert r.exit_code == 0, r.output


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """A simulated session (30 poses), its calibration and a self-calibration session."""
    d = tmp_path_factory.mktemp("inputs")
    _ok("simulate", "-o", d / "s.jsonl", "--poses", 30, "--seed", 5)
    _ok("solve", d / "s.jsonl", "-o", d / "c.yaml", "--folds", 2)
    from tmscal.sim.arm import make_arm
    selfcal_session(d / "sc.jsonl", make_arm("ur5e", "paper", 11), n=30)
    return {"session": d / "s.jsonl", "calib": d / "c.yaml", "selfcal": d / "sc.jsonl"}


@contextlib.contextmanager
def _held(path: Path) -> Iterator[None]:
    """``path`` (a session) held open for appending, under the writer's lock, by another
    process for the duration."""
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(path)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, cwd=REPO)
    try:
        assert proc.stdout.readline().strip() == b"locked"
        yield
    finally:
        proc.stdin.close()
        assert proc.wait(60) == 0


# --- item 5: --force never replaces a file another tmscal holds locked ------------------------

def test_solve_force_onto_a_session_being_recorded_is_refused(inputs, tmp_path):
    """The audit's case, through the real command line in its own process: `tmscal solve X
    -o RUNNING.jsonl --force` while another process records RUNNING.jsonl."""
    running = shutil.copy(inputs["session"], tmp_path / "running.jsonl")
    before = Path(running).read_bytes()
    with _held(running):
        r = subprocess.run([sys.executable, "-m", "tmscal.cli", "solve", str(inputs["session"]),
                            "-o", str(running), "--force"], capture_output=True, text=True,
                           timeout=120, cwd=REPO)
        assert r.returncode != 0
        assert LOCKED in r.stderr and str(running) in r.stderr
        assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
        assert Path(running).read_bytes() == before
    assert len(read_session(running, strict=True).poses) == 30  # still the session
    assert not [f for f in tmp_path.iterdir() if f.name.startswith(".tmscal-")]
    # once the other process has let go, --force replaces it as asked
    r = subprocess.run([sys.executable, "-m", "tmscal.cli", "solve", str(inputs["session"]),
                        "-o", str(running), "--force"], capture_output=True, text=True,
                       timeout=120, cwd=REPO)
    assert r.returncode == 0, r.stderr
    assert Path(running).read_text().startswith("format: tmscal-calibration")


#: every command that writes a file with --force: (its arguments, with OUT for the locked file)
FORCE_WRITERS = {
    "solve --plot": ["solve", "{session}", "--plot", "OUT", "--force"],
    "study --plot": ["study", "{session}", "--n-max", "12", "--plot", "OUT", "--force"],
    "compare --plot": ["compare", "{session}", "--plot", "DIR", "--force"],
    "export": ["export", "{calib}", "--format", "itk", "-o", "OUT", "--force"],
    "report": ["report", "{session}", "-o", "OUT", "--force"],
    "selfcal identify": ["selfcal", "identify", "{selfcal}", "-o", "OUT", "--force"],
    "simulate": ["simulate", "-o", "OUT", "--poses", "10", "--force"],
    "demo": ["demo", "-o", "OUT", "--force"],
}


@pytest.mark.parametrize("name", FORCE_WRITERS)
def test_no_command_force_replaces_a_locked_file(inputs, tmp_path, name):
    plot_dir = tmp_path / "plots"
    plot_dir.mkdir()
    out = plot_dir / "compare-errors.png" if name == "compare --plot" else tmp_path / "out"
    shutil.copy(inputs["session"], out)
    before = out.read_bytes()
    args = [a.format(**inputs) for a in FORCE_WRITERS[name]]
    args = [str(out) if a == "OUT" else str(plot_dir) if a == "DIR" else a for a in args]
    with _held(out):
        r = _cli(*args)
        assert r.exit_code != 0
        assert LOCKED in r.output and str(out) in r.output
        assert out.read_bytes() == before
    assert not [f for f in out.parent.iterdir() if f.name.startswith(".tmscal-")]


def test_the_lock_is_checked_again_when_the_file_is_put_in_place(inputs, tmp_path):
    """What the commands call last (after their slow work): every way of putting an output
    in place refuses a file that became locked meanwhile, and leaves it as it was."""
    out = Path(shutil.copy(inputs["session"], tmp_path / "s.jsonl"))
    before = out.read_bytes()
    with _held(out):
        with pytest.raises(SessionError, match=LOCKED):
            write_output(out, "X: replaced\n", overwrite=True)
        with pytest.raises(SessionError, match=LOCKED), output_path(out, overwrite=True) as t:
            t.write_bytes(b"\x89PNG")
        with pytest.raises(SessionError, match="locked"):
            SessionWriter.create(out, make_header(["marker"]), overwrite=True)
        assert out.read_bytes() == before
    assert sorted(f.name for f in tmp_path.iterdir()) == ["s.jsonl"]  # no temporary left
    write_output(out, "X: replaced\n", overwrite=True)
    assert out.read_text() == "X: replaced\n"


def test_without_overwrite_an_existing_file_is_never_replaced(tmp_path):
    out = tmp_path / "c.yaml"
    out.write_text("keep")
    with pytest.raises(SessionError, match="already exists"):
        write_output(out, "new")
    assert out.read_text() == "keep"
    assert sorted(f.name for f in tmp_path.iterdir()) == ["c.yaml"]


# --- item 7: the header is written whole or not at all ----------------------------------------

def test_disk_full_while_the_header_is_written_leaves_nothing(tmp_path, monkeypatch):
    """os.write into the folder fails with ENOSPC after 100 bytes (the header is ~2 kB):
    nothing is left at the path, nor beside it, and a new run starts there."""
    p = tmp_path / "s.jsonl"
    header = make_header(["marker", "probe"], truth=_TRUTH.as_dict(),
                         config={"note": "x" * 1500})
    real_write = os.write
    written = [0]

    def disk_full(fd: int, data) -> int:
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            target = ""
        if not target.startswith(str(tmp_path)):
            return real_write(fd, data)
        room = 100 - written[0]
        if room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        n = real_write(fd, bytes(data[:room]))
        written[0] += n
        return n

    monkeypatch.setattr(session_mod.os, "write", disk_full)
    with pytest.raises(SessionError, match=r"s\.jsonl: cannot write session file \(No space"):
        SessionWriter.create(p, header)
    assert written[0] == 100  # the fault struck part way through the header
    monkeypatch.setattr(session_mod.os, "write", real_write)
    assert not os.path.lexists(p)
    assert list(tmp_path.iterdir()) == []
    with SessionWriter.create(p, header) as w:  # a new run can start at the path
        pass
    with SessionWriter.resume(p) as w:
        assert w.session.header["config"]["note"] == "x" * 1500


def test_a_new_session_is_locked_before_it_has_its_name(tmp_path):
    """No moment in which the new session is at its path without the writer's lock."""
    import fcntl

    p = tmp_path / "s.jsonl"
    seen: list[bool] = []
    real_link = os.link

    def spy(src, dst, *a, **kw):
        fd = os.open(src, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            seen.append(False)
        except BlockingIOError:
            seen.append(True)
        finally:
            os.close(fd)
        return real_link(src, dst, *a, **kw)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(os, "link", spy)
        w = SessionWriter.create(p, make_header(["marker"]))
    try:
        assert seen == [True]
    finally:
        w.close()


# --- item 10: outputs are created with the umask's mode ---------------------------------------

@pytest.fixture
def umask():
    old = os.umask(0o022)

    def set_(m: int) -> None:
        os.umask(m)

    yield set_
    os.umask(old)


def _mode(p: Path) -> int:
    return stat.S_IMODE(p.stat().st_mode)


def test_every_output_kind_follows_the_umask(inputs, tmp_path, umask):
    d = tmp_path
    _ok("simulate", "-o", d / "s.jsonl", "--poses", 30, "--seed", 6)
    _ok("solve", inputs["session"], "-o", d / "c.yaml", "--plot", d / "r.png", "--folds", 2)
    for fmt, name in (("itk", "Z.tfm"), ("plus", "plus.xml"), ("easy-handeye", "he.yaml"),
                      ("invesalius", "r.rbtf"), ("json", "c.json")):
        _ok("export", inputs["calib"], "--format", fmt, "-o", d / name)
    _ok("report", inputs["session"], "-o", d / "report.html", "--folds", 2)
    _ok("study", inputs["session"], "--plot", d / "study.png", "--n-max", 12, "--methods",
        "qr36")
    _ok("compare", inputs["session"], "--plot", d / "cmp", "--methods", "qr36", "--n", "8,10",
        "--folds", 2)
    _ok("selfcal", "identify", inputs["selfcal"], "-o", d / "kin.yaml")
    outputs = sorted(p for p in d.rglob("*") if p.is_file())
    assert {p.name for p in outputs} >= {"s.jsonl", "c.yaml", "r.png", "Z.tfm", "plus.xml",
                                         "he.yaml", "r.rbtf", "c.json", "report.html",
                                         "study.png", "compare-errors.png", "compare-time.png",
                                         "kin.yaml"}
    assert {p.name: oct(_mode(p)) for p in outputs} == {p.name: "0o644" for p in outputs}
    # another umask: it is the umask, not a fixed 0644
    umask(0o002)
    _ok("export", inputs["calib"], "--format", "itk", "-o", d / "Z2.tfm")
    write_session(d / "s2.jsonl", make_header(["marker"]), [])
    assert oct(_mode(d / "Z2.tfm")) == oct(_mode(d / "s2.jsonl")) == "0o664"


def test_force_replaces_with_the_umask_mode_too(inputs, tmp_path, umask):
    out = tmp_path / "Z.tfm"
    out.write_text("old")
    os.chmod(out, 0o600)
    _ok("export", inputs["calib"], "--format", "itk", "-o", out, "--force")
    assert oct(_mode(out)) == "0o644"
