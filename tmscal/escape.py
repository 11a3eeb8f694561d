"""Text from files (a session's config name, a device's identity, a calibration file's name or
method, a ROM path) made safe for each kind of output tmscal writes: one helper per kind,
used by every writer of that kind (the PLUS export, the HTML report, the text tables).

- :func:`visible`: for a terminal or any text output. Control characters (C0 but tab, DEL,
  C1), bidirectional overrides, embeddings, isolates and marks (U+202E RIGHT-TO-LEFT OVERRIDE
  and its kin, which reorder what a reader sees), line and paragraph separators, the
  non-characters U+FFFE/U+FFFF and lone surrogates are shown as visible escapes, ``\\x1b``,
  ``\\u202e``; newlines too unless ``newlines``. The result is printable and cannot move
  the cursor, ring a bell or reorder the line around it.
- XML 1.0 (:func:`xml_text`, :func:`xml_attr`, :func:`xml_comment`): the characters XML
  1.0 does not allow at all (controls but tab, newline, carriage return; U+FFFE/U+FFFF;
  surrogates) cannot even be written as character references, so they are made visible
  first; then ``& < >`` (and quotes in attributes) become entities; in a comment, which
  has no entities, ``--`` is split ("- -") and a trailing ``-`` gets a space.
- HTML (:func:`html_text`): :func:`visible`, then ``& < > " '`` as entities.
- A value of a device's identity or a check's measurements (:func:`value_text`): a mapping
  as ``{marker: 1, probe: 2}`` and a list as ``[0.0, 0.0, 0.0]`` (YAML's flow style, the
  configs' own), never Python's ``{'marker': 1}`` repr; then :func:`visible`.
"""

from __future__ import annotations

import html
import re

__all__ = ["visible", "xml_text", "xml_attr", "xml_comment", "html_text", "value_text"]

#: what :func:`visible` escapes (besides newline and carriage return, unless kept)
_UNSAFE = re.compile(
    "[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f"  # C0 controls but tab, LF, CR; DEL; C1 controls
    "\u061c\u200e\u200f\u202a-\u202e\u2066-\u2069"  # bidi marks, embeddings, overrides, isolates
    "\u2028\u2029"  # line and paragraph separators
    "\ufffe\uffff\ud800-\udfff]"  # not characters; lone surrogates
)
_UNSAFE_LINES = re.compile(_UNSAFE.pattern[:-1] + "\n\r]")


def _escape(m: re.Match[str]) -> str:
    c = ord(m.group())
    return f"\\x{c:02x}" if c <= 0xFF else f"\\u{c:04x}"


def visible(s: object, newlines: bool = False) -> str:
    """``str(s)`` with every control, bidi-control, separator and non-character shown as
    a visible escape (``\\x1b``, ``\\u202e``); tab kept, and with ``newlines`` newline and
    carriage return kept too (for a block of several lines)."""
    return (_UNSAFE if newlines else _UNSAFE_LINES).sub(_escape, str(s))


def xml_text(s: object) -> str:
    """Element text for an XML 1.0 document: :func:`visible` (newlines kept), then
    ``& < >`` as entities."""
    return (visible(s, newlines=True).replace("&", "&amp;").replace("<", "&lt;")
            .replace(">", "&gt;"))


def xml_attr(s: object) -> str:
    """An XML 1.0 attribute value, quotes included (``"…"``): :func:`visible` on one line,
    then ``& < > " '`` and tab as entities."""
    v = (xml_text(visible(s)).replace('"', "&quot;").replace("'", "&apos;")
         .replace("\t", "&#9;"))  # a parser turns a raw tab in an attribute into a space
    return f'"{v}"'


def xml_comment(s: object) -> str:
    """The body of an XML comment (``<!-- … -->``): :func:`visible` on one line, no
    ``--`` (split into ``- -``) and no trailing ``-``, which XML forbids in a comment."""
    v = re.sub("-(?=-)", "- ", visible(s))
    return v + " " if v.endswith("-") else v


def html_text(s: object, newlines: bool = False) -> str:
    """Text or an attribute value (between double quotes) of an HTML page:
    :func:`visible`, then ``& < > " '`` as entities."""
    return html.escape(visible(s, newlines=newlines), quote=True)


def value_text(v: object) -> str:
    """``v`` for a line of text output: a mapping as ``{key: value, …}``, a list or tuple as
    ``[a, b, …]`` (YAML's flow style, recursively; no quotes), anything else as ``str``;
    made :func:`visible`."""
    def text(x: object) -> str:
        if isinstance(x, dict):
            return "{" + ", ".join(f"{text(k)}: {text(y)}" for k, y in x.items()) + "}"
        if isinstance(x, (list, tuple)):
            return "[" + ", ".join(text(y) for y in x) + "]"
        return str(x)
    return visible(text(v))
