"""Every file tmscal writes (a calibration, an export, a report, a plot, a kinematics file, a
session's first line) goes through here: written whole or not at all, created with the
umask's mode, and never put over a file another tmscal process holds locked.

- **Whole or not at all.** The data goes to a new temporary file in the destination's folder
  (``.tmscal-XXXXXXXX<suffix>``), is fsynced, and only then gets the destination's name; a
  failure (a full disk, Ctrl-C) removes the temporary file and leaves the destination as it
  was.
- **The umask's mode.** Files are created with mode 0666 masked by the process umask (0644
  under the usual umask 022), as ``open()`` and every other program create files, so that
  the account of a navigation computer can read ``calib.yaml``, ``Z.tfm`` or a report. (A
  temporary file made by ``tempfile.mkstemp`` would be 0600 whatever the umask.)
- **Never over a locked file.** A session being recorded is held locked by its
  ``SessionWriter`` (``flock``, docs/session-format.md). Without ``overwrite`` the new file is
  linked into place (``link``: an existing file, even one created a moment ago, is refused);
  with ``overwrite`` (the CLI's ``--force``) the existing file is locked by this process
  first, non-blocking, and replaced while that lock is held, so a file another tmscal holds
  is refused with SessionError ("in use by another tmscal process") and left as it is.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import secrets
from collections.abc import Iterator
from pathlib import Path

from ..errors import SessionError

__all__ = ["check_not_locked", "output_path", "write_output"]

#: the mode new files are created with, before the umask
MODE = 0o666

#: errno values of a file system that has no hard links (vfat, some network or FUSE mounts)
_NO_LINKS = {errno.EPERM, errno.EOPNOTSUPP, errno.ENOSYS, errno.EMLINK, errno.EXDEV}


def _why(e: OSError) -> str:
    return e.strerror or str(e)


def _in_use(p: Path) -> SessionError:
    return SessionError(f"{p}: in use by another tmscal process (locked: a session being "
                        "recorded); it is never replaced, not even with --force. Wait for it "
                        "to finish or stop it, or write to another file")


@contextlib.contextmanager
def _held(p: Path) -> Iterator[None]:
    """Hold an exclusive, non-blocking ``flock`` on the file at ``p`` (if there is one) for
    the duration; SessionError when another process (or another open file of this one)
    holds it."""
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        yield
        return
    except OSError as e:
        raise SessionError(f"{p}: cannot check whether another tmscal process is writing it "
                           f"({_why(e)}); not replaced") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise _in_use(p) from None
        except OSError as e:
            if e.errno not in (errno.ENOLCK, errno.EINVAL, errno.ENOTSUP):
                raise SessionError(f"{p}: cannot lock it ({_why(e)}); not replaced") from None
            # a file system without flock: nobody can hold it locked either
        yield
    finally:
        os.close(fd)


def check_not_locked(path: str | os.PathLike[str]) -> None:
    """Raise SessionError if another tmscal process holds ``path`` locked (a session being
    recorded); nothing if the file is free or does not exist. For refusing early, before
    slow work; :func:`output_path` checks again when it puts the file in place."""
    with _held(Path(path)):
        pass


def fsync_dir(p: Path) -> None:
    """fsync the folder of ``p`` so that a new name in it survives a power cut (best
    effort: some file systems cannot)."""
    try:
        dfd = os.open(p.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dfd)
    except OSError:
        pass
    finally:
        os.close(dfd)


def new_temp(p: Path, flags: int = os.O_WRONLY) -> tuple[int, Path]:
    """Create a new, empty temporary file next to ``p`` (same folder, same suffix, mode
    0666 & ~umask, O_EXCL): (its fd, its path)."""
    suffix = p.suffix if len(p.suffix) <= 16 else ""
    for _ in range(100):
        tmp = p.parent / f".tmscal-{secrets.token_hex(4)}{suffix}"
        try:
            fd = os.open(tmp, flags | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0),
                         MODE)
        except FileExistsError:
            continue
        except OSError as e:
            raise SessionError(f"{p}: cannot write ({_why(e)})") from None
        return fd, tmp
    raise SessionError(f"{p}: cannot create a temporary file in {p.parent}")


def install(tmp: Path, p: Path, overwrite: bool, hint: str = "choose another name") -> None:
    """Give the complete file ``tmp`` the name ``p`` (same folder). Without ``overwrite``:
    ``link``, so an existing ``p`` is never replaced (SessionError "already exists"); on a
    file system without hard links, a rename after checking that ``p`` does not exist. With
    ``overwrite``: a rename while ``p``'s lock is held by us (SessionError if another process
    holds it). ``tmp`` is gone afterwards unless this raises. ``hint`` ends the message of
    "already exists"."""
    if overwrite:
        with _held(p):
            try:
                os.replace(tmp, p)
            except OSError as e:
                raise SessionError(f"{p}: cannot write ({_why(e)})") from None
        return
    try:
        os.link(tmp, p)
    except FileExistsError:
        raise SessionError(f"{p}: already exists; refusing to overwrite it ({hint})") \
            from None
    except OSError as e:
        if e.errno not in _NO_LINKS:
            raise SessionError(f"{p}: cannot write ({_why(e)})") from None
        if os.path.lexists(p):
            raise SessionError(f"{p}: already exists; refusing to overwrite it ({hint})") \
                from None
        try:
            os.rename(tmp, p)
        except OSError as e2:
            raise SessionError(f"{p}: cannot write ({_why(e2)})") from None
        return
    try:
        os.unlink(tmp)
    except OSError:
        pass


def _prepare(path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise SessionError(f"{p}: cannot write ({_why(e)})") from None
    if p.is_dir():
        raise SessionError(f"{p}: is a directory")
    return p


@contextlib.contextmanager
def output_path(path: str | os.PathLike[str], overwrite: bool = False) -> Iterator[Path]:
    """A temporary path (an empty file, mode 0666 & ~umask, the same suffix) to write the
    output ``path`` to, e.g. with matplotlib's ``savefig``; when the block ends normally the
    file is fsynced and put in place (:func:`install`), when it raises the temporary file is
    removed and ``path`` is left as it was. SessionError as :func:`install` says."""
    p = _prepare(path)
    fd, tmp = new_temp(p)
    os.close(fd)
    try:
        yield tmp
        try:
            fd = os.open(tmp, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError as e:
            raise SessionError(f"{p}: cannot write ({_why(e)})") from None
        install(tmp, p, overwrite)
        fsync_dir(p)
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)


def write_output(path: str | os.PathLike[str], data: str | bytes,
                 overwrite: bool = False) -> Path:
    """Write ``data`` (str as UTF-8) to ``path`` whole or not at all, mode 0666 & ~umask;
    never over an existing file without ``overwrite``, never over a file another tmscal
    process holds locked (SessionError naming the file). Returns the path."""
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    with output_path(path, overwrite) as tmp:
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_TRUNC | getattr(os, "O_CLOEXEC", 0))
        except OSError as e:
            raise SessionError(f"{path}: cannot write ({_why(e)})") from None
        try:
            view = memoryview(raw)
            while view:
                view = view[os.write(fd, view):]
        except OSError as e:
            raise SessionError(f"{path}: cannot write ({_why(e)})") from None
        finally:
            os.close(fd)
    return Path(path)
