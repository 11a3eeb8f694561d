"""CRC-16/ARC as the NDI Combined API uses it (poly 0x8005 reflected, init 0, no final XOR):
on every text command and reply (4 uppercase hex digits) and on a BX reply's header and body
(uint16, little-endian). NDI's Polaris Application Program Interface Guide, "Calculating
the CRC"."""

from __future__ import annotations

__all__ = ["crc16", "crc_hex"]


def _make_table() -> list[int]:
    table = []
    for byte in range(256):
        c = byte
        for _ in range(8):
            c = (c >> 1) ^ 0xA001 if c & 1 else c >> 1
        table.append(c)
    return table


_CRC_TABLE = _make_table()


def crc16(data: bytes | bytearray | memoryview | str, crc: int = 0) -> int:
    """CRC-16/ARC of ``data`` (str is encoded as ASCII), continuing from ``crc``.

    ``crc16(b"123456789") == 0xBB3D``; ``crc16(b"OKAY") == 0xA896``.
    """
    if isinstance(data, str):
        data = data.encode("ascii")
    table = _CRC_TABLE
    for b in bytes(data):
        crc = (crc >> 8) ^ table[(crc ^ b) & 0xFF]
    return crc


def crc_hex(data: bytes | str) -> str:
    """The CRC of ``data`` as 4 uppercase hex digits, as NDI appends it to text."""
    return f"{crc16(data):04X}"
