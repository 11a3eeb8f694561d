"""NDI Combined API commands, both directions: the host encodes them, the mock decodes them.

``CMD:params`` + 4 uppercase hex CRC + ``\\r`` (colon form) or ``CMD params\\r`` (space form,
no CRC); plus the parameters of PVWR (a tool definition written in 64-byte chunks).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from ...errors import ProtocolError
from .codes import DEVICE, ErrorCode, error_text
from .crc import crc_hex

__all__ = ["Command", "encode_command", "parse_command", "pvwr_params", "rom_chunks"]

_NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9]*")
_NOT_A_COMMAND = ErrorCode.INVALID_COMMAND
_BAD_COMMAND_CRC = ErrorCode.BAD_COMMAND_CRC


def encode_command(name: str, params: str = "", *, crc: bool = True) -> bytes:
    """Bytes for command ``name`` with ``params``.

    ``crc=True``: colon form ``NAME:params`` + CRC (4 uppercase hex of everything from the
    first letter through the last parameter) + ``\\r``. ``crc=False``: space form
    ``NAME params\\r``. ``encode_command("INIT") == b"INIT:E3A5\\r"``.
    """
    if not _NAME_RE.fullmatch(name):
        raise ValueError(f"invalid NDI command name {name!r}")
    if "\r" in params or "\n" in params:
        raise ValueError(f"NDI command parameters must not contain CR/LF: {params!r}")
    if crc:
        body = f"{name.upper()}:{params}"
        return (body + crc_hex(body) + "\r").encode("ascii")
    return f"{name.upper()} {params}\r".encode("ascii")


@dataclass(frozen=True)
class Command:
    """A decoded command: upper-case ``name``, raw ``params`` (case kept) and whether it
    came in the colon form with a (valid) CRC."""

    name: str
    params: str
    had_crc: bool


def _refuse(message: str, code: int) -> ProtocolError:
    return ProtocolError(message, code=int(code), text=error_text(code), device=DEVICE)


def parse_command(line: bytes) -> Command:
    """Decode one command line (with or without its trailing ``\\r``).

    Raises ``ProtocolError`` with ``code=0x04`` when the CRC of a colon-form command does not
    match, ``code=0x01`` when the line is not a command at all (non-ASCII, no name).
    """
    raw = bytes(line)
    if raw.endswith(b"\r"):
        raw = raw[:-1]
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise _refuse(f"command is not ASCII: {raw[:40]!r}", _NOT_A_COMMAND) from None
    colon = text.find(":")
    space = text.find(" ")
    if colon >= 0 and (space < 0 or colon < space):
        name, rest = text[:colon], text[colon + 1:]
        if len(rest) < 4:
            raise _refuse(f"command {text!r} has no CRC", _BAD_COMMAND_CRC)
        params, crc_field = rest[:-4], rest[-4:]
        expected = crc_hex(text[:-4])
        if crc_field.upper() != expected:
            raise _refuse(f"command {text!r}: CRC {crc_field!r} != {expected}",
                          _BAD_COMMAND_CRC)
        had_crc = True
    elif space >= 0:
        name, params, had_crc = text[:space], text[space + 1:], False
    else:
        name, params, had_crc = text, "", False
    if not _NAME_RE.fullmatch(name):
        raise _refuse(f"not a command: {text[:40]!r}", _NOT_A_COMMAND)
    return Command(name.upper(), params, had_crc)


def pvwr_params(handle: int, address: int, chunk: bytes) -> str:
    """PVWR parameters: ``hh`` + ``aaaa`` + 128 uppercase hex chars for a 64-byte chunk."""
    if len(chunk) != 64:
        raise ValueError(f"PVWR chunks are 64 bytes, got {len(chunk)}")
    return f"{handle:02X}{address:04X}{chunk.hex().upper()}"


def rom_chunks(rom: bytes, pad_to: int = 64) -> list[tuple[int, bytes]]:
    """Split a tool definition into (address, 64-byte chunk) pairs, zero-padded to a multiple
    of ``pad_to`` (64; ndicapi uses 1024)."""
    if pad_to % 64:
        raise ValueError("pad_to must be a multiple of 64")
    size = max(pad_to, -(-len(rom) // pad_to) * pad_to)
    data = rom + bytes(size - len(rom))
    return [(a, data[a:a + 64]) for a in range(0, size, 64)]
