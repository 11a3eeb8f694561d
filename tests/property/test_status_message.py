"""Property tests of the monitor's OpenIGTLink STATUS message
(``tmscal.drivers.igtl.wire.StatusMessage``): any code, subcode, error name and status string
packs into a message whose header and CRC the OpenIGTLink parser of the igtl driver accepts,
whose content is laid out as the specification says (uint16 code, int64 subcode, char[20] error
name, zero-terminated string: unpacked here with ``struct``), and which unpacks back to what was
sent; a name over 20 bytes is cut."""

from __future__ import annotations

import struct

from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.drivers.igtl import wire
from tmscal.drivers.igtl.wire import StatusMessage

text = st.text(st.characters(min_codepoint=1, max_codepoint=0x10FFFF,
                             blacklist_categories=("Cs",)), max_size=200)
ascii_name = st.text(st.characters(min_codepoint=0x21, max_codepoint=0x7E), max_size=30)


@fuzz_settings()
@given(st.integers(0, 0xFFFF), st.integers(-2**63, 2**63 - 1), ascii_name, text,
       st.floats(0, 4e9, allow_nan=False))
def test_status_round_trip(code: int, subcode: int, name: str, status: str,
                           stamp: float) -> None:
    data = StatusMessage(code, subcode, name, status, timestamp=stamp,
                         device_name="TMSCalMonitor").pack()
    h = wire.parse_header(data[:wire.HEADER_SIZE])
    assert (h.type, h.device, h.body_size) == ("STATUS", "TMSCalMonitor",
                                               len(data) - wire.HEADER_SIZE)
    content, meta, _ = wire.split_body(h, data[wire.HEADER_SIZE:])  # the CRC checked
    assert meta == {}
    c, s, n = struct.unpack(">Hq20s", content[:30])
    assert (c, s) == (code, subcode)
    assert n.rstrip(b"\0") == name.encode()[:20]
    assert content[30:] == status.encode("utf-8") + b"\0"
    back = StatusMessage()
    back._unpack_content(content)
    assert (back.code, back.subcode, back.error_name, back.status_string) == (
        code, subcode, name[:20], status)
