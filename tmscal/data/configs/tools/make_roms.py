"""Generate the small, deterministic tool-definition (.rom) files used by the Polaris mock
and its tests. These are NOT real NDI tool definitions: they only need to be plausible
binary blobs with distinct bytes, because the mock identifies a loaded tool by comparing the
bytes written with PVWR (zero padding stripped) with the files it was configured with.

Layout (little-endian): 4-byte magic ``NDI\\0``, 2-byte format version, 2-byte marker count,
32-byte ASCII tool name (zero padded), 16-byte ASCII part number, then the marker positions
of the 8700340-like geometry as float32 (x, y, z) mm, then filler bytes from a SHA-256 chain
seeded with the tool name, up to 600 bytes (not a multiple of 64, so padding gets exercised).
The last byte is forced non-zero so stripping zero padding never eats content.

Usage: ``python configs/tools/make_roms.py`` (writes next to this script). Re-running gives
byte-identical files.
"""

from __future__ import annotations

import hashlib
import struct
from pathlib import Path

#: 8700340-like planar four-sphere geometry (mm), centred (same as tmscal.sim.rig).
_SPHERES = [(0.0, 0.0, 0.0), (50.0, 0.0, 0.0), (99.73, 25.75, 0.0), (136.23, -22.05, 0.0)]
SIZE = 600
TOOLS = {"marker-8700340.rom": "tmscal marker 8700340-like",
         "probe-8700340.rom": "tmscal probe 8700340-like"}


def rom_bytes(name: str) -> bytes:
    """Deterministic tool-definition blob for tool ``name``."""
    cx = sum(p[0] for p in _SPHERES) / 4
    cy = sum(p[1] for p in _SPHERES) / 4
    out = bytearray(b"NDI\0")
    out += struct.pack("<HH", 1, len(_SPHERES))
    out += name.encode("ascii")[:32].ljust(32, b"\0")
    out += b"8700340".ljust(16, b"\0")
    for x, y, z in _SPHERES:
        out += struct.pack("<3f", x - cx, y - cy, z)
    h = hashlib.sha256(name.encode("ascii")).digest()
    while len(out) < SIZE:
        out += h
        h = hashlib.sha256(h).digest()
    out = out[:SIZE]
    if out[-1] == 0:
        out[-1] = 0x5A
    return bytes(out)


def main() -> None:
    here = Path(__file__).resolve().parent
    for fname, name in TOOLS.items():
        (here / fname).write_bytes(rom_bytes(name))


if __name__ == "__main__":
    main()
