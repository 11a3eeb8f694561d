"""Which kind of tmscal file a text is, from its first lines, so that a file given where
another kind is expected gets one message saying what it is and what was expected (a session
given to ``track``, a rig config given to ``solve``, a session given as ``--calib``, …).

Kinds (:data:`KINDS`): ``session`` (JSON Lines, a header with format ``tmscal-session``),
``config`` (a rig config: YAML with ``robot``/``tracker``/``plan``/``safety`` sections),
``calibration`` (``format: tmscal-calibration``, YAML of ``solve -o`` or the ``json``
export), ``kinematics`` (``format: tmscal-kinematics``), and the exports other programs read
(``itk``, ``plus``, ``easy-handeye``, ``invesalius``), the HTML report and a URDF (``urdf``,
an arm's description, XML with a ``<robot>`` element). The sniffing reads
keys and first lines only; it never decides whether a file is valid (the readers do).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

__all__ = ["KINDS", "THIS_COMMAND", "sniff", "wrong_kind", "read_kind"]

#: kind → (what such a file is, how to recognise it or where it comes from)
KINDS: dict[str, tuple[str, str]] = {
    "session": ("a tmscal session", "JSON Lines: a header, then one pose per line; written by "
                "acquire, simulate or selfcal acquire"),
    "config": ("a rig config", "YAML with robot, tracker, plan and safety sections, e.g. "
               "configs/mock-ur-polaris.yaml"),
    "calibration": ("a calibration file", "written by tmscal solve -o or tmscal export "
                    "--format json"),
    "kinematics": ("a kinematics file", "written by tmscal selfcal identify -o"),
    "itk": ("an ITK transform file", "tmscal export --format itk"),
    "plus": ("a PLUS device set", "tmscal export --format plus"),
    "easy-handeye": ("an easy_handeye calibration", "tmscal export --format easy-handeye"),
    "invesalius": ("an InVesalius robot co-registration file",
                   "tmscal export --format invesalius"),
    "report": ("an HTML report", "tmscal report"),
    "measurements": ("a measurement CSV", "joints and measured poses, one row per pose, for "
                     "tmscal import"),
    "urdf": ("a URDF", "a ROS robot description: XML with a <robot> element"),
}

#: the words a message uses for the command; the CLI puts the command's name in their place
THIS_COMMAND = "this command"

#: the top-level sections of a rig config (tmscal.config)
_CONFIG_KEYS = {"robot", "tracker", "plan", "sampling", "safety", "run", "mock", "adaptive",
                "ft"}
_FORMATS = {"tmscal-session": "session", "tmscal-calibration": "calibration",
            "tmscal-kinematics": "kinematics"}
_TOP_KEY = re.compile(r"^([A-Za-z_][\w-]*)\s*:(.*)$")
_SNIFF_CHARS = 65536


def sniff(text: str) -> str | None:
    """The kind (a key of :data:`KINDS`) of a file whose text starts with ``text``, or None
    when it looks like none of them. Only the first 64 KiB are looked at."""
    head = text[:_SNIFF_CHARS].lstrip("\ufeff")
    stripped = head.lstrip()
    if stripped.startswith("#Insight Transform File"):
        return "itk"
    if stripped.startswith("<"):
        low = stripped[:2000].lower()
        if "<plusconfiguration" in low:
            return "plus"
        if "<html" in low or "<!doctype html" in low:
            return "report"
        if re.search(r"<robot[\s>]", low):
            return "urdf"
        return None
    if stripped.startswith("{"):
        return _sniff_json(stripped)
    if re.fullmatch(r"(?:[-+0-9.eE]+[\t ]*\r?\n)+[-+0-9.eE]*\s*", stripped[:4000] + "\n"):
        return "invesalius" if stripped.count("\n") >= 40 else None
    keys: dict[str, str] = {}
    for line in head.splitlines():
        m = _TOP_KEY.match(line)
        if m:
            keys.setdefault(m.group(1), m.group(2).strip().strip("'\""))
    fmt = keys.get("format")
    if fmt in _FORMATS:
        return _FORMATS[fmt]
    if "transformation" in keys and "parameters" in keys or (
            "transform" in keys and "parameters" in keys):
        return "easy-handeye"
    if {"robot", "tracker", "ft"} & keys.keys() and set(keys) - {"name", "description"} \
            <= _CONFIG_KEYS:
        return "config"
    return None


def _sniff_json(text: str) -> str | None:
    first = text.split("\n", 1)[0]
    try:
        obj = json.loads(first)
    except (ValueError, RecursionError):  # e.g. one object over several lines: a JSON export
        obj = None
        fmt = re.search(r'"format"\s*:\s*"([^"]{0,40})"', text[:4000])
        if fmt and fmt.group(1) in _FORMATS:
            return _FORMATS[fmt.group(1)]
        return None
    if isinstance(obj, dict):
        fmt = obj.get("format")
        if fmt in _FORMATS:
            return _FORMATS[fmt]
        if obj.get("kind") == "header":
            return "session"
        if _CONFIG_KEYS & obj.keys() and {"robot", "tracker"} & obj.keys():
            return "config"
    return None


def wrong_kind(src: str, text: str, expected: str) -> str | None:
    """The message for a file ``src`` that is of another kind than ``expected`` (a key of
    :data:`KINDS`): what it is and what the command expects; None when it is of the expected
    kind or of no kind known here (then the reader's own error says what is wrong)."""
    kind = sniff(text)
    if kind is None or kind == expected:
        return None
    name, how = KINDS[kind]
    want, want_how = KINDS[expected]
    return f"{src} is {name} ({how}); {THIS_COMMAND} expects {want} ({want_how})"


def read_kind(p: Path, kind: str, noun: str, max_bytes: int,
              error: type[Exception]) -> str:
    """The UTF-8 text of the regular file ``p`` that should be of ``kind`` (:data:`KINDS`; a
    ``noun`` in messages, e.g. "config", "calibration file"), at most ``max_bytes`` long.
    Every problem is one ``error`` naming the file: not a regular file, too large, unreadable
    (the OS's reason), not UTF-8, or another kind of tmscal file (:func:`wrong_kind`: a
    session given as a config, …)."""
    src = str(p)
    try:
        if p.exists() and not p.is_file():
            raise error(f"{src}: not a regular file")
        if p.stat().st_size > max_bytes:
            raise error(f"{src}: larger than {max_bytes:,} bytes; not a {noun}")
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise error(f"{src}: cannot read {noun} ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise error(f"{src}: not a UTF-8 text file") from None
    msg = wrong_kind(src, text, kind)
    if msg is not None:
        raise error(msg)
    return text
