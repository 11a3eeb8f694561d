"""NDI Combined API codec against golden vectors (from NDI's Polaris API Guide and replies
captured from real devices) and hand-built replies."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from tmscal.drivers.ndi import protocol as p
from tmscal.errors import DeviceError, ProtocolError

# --- CRC: every check value of the sheet ------------------------------------------------------

CRC_VECTORS = [
    ("123456789", 0xBB3D), ("OKAY", 0xA896), ("RESET", 0xBE6F), ("INIT:", 0xE3A5),
    ("VER:0", 0x65EE), ("COMM:50000", 0x0048), ("TSTART:", 0x5423), ("TSTOP:", 0x2C14),
    ("BX:0801", 0x00EC), ("TX:0801", 0xC19B), ("PHSR:01", 0xE03E),
    ("PHRQ:*********1****", 0xA4C1), ("GETINFO:Features.Firmware.Version", 0x0492),
    ("1", 0xD4C1),
]


@pytest.mark.parametrize(("text", "crc"), CRC_VECTORS)
def test_crc_check_values(text: str, crc: int) -> None:
    assert p.crc16(text.encode("ascii")) == crc
    assert p.crc_hex(text) == f"{crc:04X}"


def test_crc_is_incremental() -> None:
    assert p.crc16(b"56789", p.crc16(b"1234")) == 0xBB3D


# --- commands -----------------------------------------------------------------------------------

@pytest.mark.parametrize(("name", "params", "wire"), [
    ("INIT", "", b"INIT:E3A5\r"),
    ("VER", "0", b"VER:065EE\r"),
    ("COMM", "50000", b"COMM:500000048\r"),
    ("TSTART", "", b"TSTART:5423\r"),
    ("TSTOP", "", b"TSTOP:2C14\r"),
    ("BX", "0801", b"BX:080100EC\r"),
    ("TX", "0801", b"TX:0801C19B\r"),
    ("PHSR", "01", b"PHSR:01E03E\r"),
    ("PHRQ", "*********1****", b"PHRQ:*********1****A4C1\r"),
    ("GETINFO", "Features.Firmware.Version", b"GETINFO:Features.Firmware.Version0492\r"),
])
def test_encode_command_colon_form(name: str, params: str, wire: bytes) -> None:
    assert p.encode_command(name, params) == wire
    cmd = p.parse_command(wire)
    assert (cmd.name, cmd.params, cmd.had_crc) == (name, params, True)


def test_space_form() -> None:
    assert p.encode_command("INIT", crc=False) == b"INIT \r"
    assert p.encode_command("PINIT", "0A", crc=False) == b"PINIT 0A\r"
    cmd = p.parse_command(b"pinit 0a\r")
    assert (cmd.name, cmd.params, cmd.had_crc) == ("PINIT", "0a", False)


def test_parse_command_keeps_lowercase_params_and_checks_crc() -> None:
    body = "PINIT:0a"
    cmd = p.parse_command((body + p.crc_hex(body)).encode())
    assert cmd.params == "0a"
    with pytest.raises(ProtocolError) as ei:
        p.parse_command(b"INIT:E3A6\r")
    assert ei.value.code == 0x04
    with pytest.raises(ProtocolError) as ei:
        p.parse_command(b"TSTART:\r")  # colon form without CRC
    assert ei.value.code == 0x04
    with pytest.raises(ProtocolError) as ei:
        p.parse_command(b"\xff\xfe\r")
    assert ei.value.code == 0x01


def test_encode_command_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError):
        p.encode_command("IN IT")
    with pytest.raises(ValueError):
        p.encode_command("VER", "0\r")


# --- replies ------------------------------------------------------------------------------------

def test_reply_framing_golden() -> None:
    assert p.frame_reply("OKAY") == b"OKAYA896\r"
    assert p.frame_reply("RESET") == b"RESETBE6F\r" == p.RESET_REPLY
    assert p.frame_reply("1") == b"1D4C1\r"


def test_parse_reply_kinds() -> None:
    assert p.parse_reply(b"OKAYA896\r").kind == "okay"
    assert p.parse_reply(b"RESETBE6F\r").kind == "reset"
    r = p.parse_reply(p.frame_reply("WARNING02"))
    assert (r.kind, r.code, r.meaning) == ("warning", 2, "tool violates unique geometry")
    r = p.parse_reply(p.frame_reply("0A"))
    assert (r.kind, r.text) == ("data", "0A")


def test_error_reply_raises_device_error_with_code_and_meaning() -> None:
    r = p.parse_reply(p.frame_reply("ERROR0C"))
    assert (r.kind, r.code) == ("error", 0x0C)
    with pytest.raises(DeviceError) as ei:
        p.raise_for_error(r, "TX:0801")
    e = ei.value
    assert not isinstance(e, ProtocolError)
    assert e.code == 12
    assert e.text == "command is invalid while in the current mode"
    assert "TX:0801" in str(e) and "ERROR0C" in str(e)


@pytest.mark.parametrize("code", [0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0A,
                                  0x0B, 0x0C, 0x0D, 0x0E, 0x0F, 0x10, 0x11, 0x12, 0x13, 0x14,
                                  0x15, 0x16, 0x17, 0x19, 0x1A, 0x1C, 0x1E, 0x1F, 0x21, 0x22,
                                  0x23, 0x24, 0x25, 0x28, 0x2A, 0x2B, 0x2C, 0x2D, 0x2E, 0x2F,
                                  0x30, 0x32, 0x33, 0x3B, 0x3C, 0x3D, 0x40, 0x41, 0x42, 0xF1,
                                  0xF4, 0xF5, 0xF6])
def test_every_sheet_error_code_has_a_meaning(code: int) -> None:
    assert code in p.ERROR_TEXTS
    assert not p.error_text(code).startswith("unknown")


def test_unknown_codes_are_named() -> None:
    assert p.error_text(0x99) == "unknown error 0x99"
    assert p.warning_text(0x77) == "unknown warning 0x77"
    assert set(p.WARNING_TEXTS) == {1, 2, 3, 4, 5}


@pytest.mark.parametrize("raw", [
    b"OKAYA897\r",       # CRC off by one
    b"OKAYA896",         # torn: no CR
    b"OK\r",             # too short for a CRC
    b"OKAYZZZZ\r",       # CRC not hex
    b"OKAY+896\r",       # int() would accept a sign; we must not
    b"OKAYA896\rOK",     # two replies
    b"\xffKAYA896\r",    # not ASCII
])
def test_bad_text_replies_raise_protocol_error(raw: bytes) -> None:
    with pytest.raises(ProtocolError):
        p.parse_reply(raw)


def test_malformed_error_reply() -> None:
    with pytest.raises(ProtocolError):
        p.parse_reply(p.frame_reply("ERRORXY"))


# --- TX -----------------------------------------------------------------------------------------

SHEET_TX = ("0101+10000+00000+00000+00000+001050-002025-150000+01234000000310000000A\n0000")


def test_decode_sheet_tx_example() -> None:
    tx = p.decode_tx(SHEET_TX)
    assert tx.system_status == 0
    (r,) = tx.records
    assert r.handle == 1 and r.status == "valid"
    assert r.quaternion == pytest.approx((1.0, 0.0, 0.0, 0.0))
    assert r.translation_mm == pytest.approx((10.5, -20.25, -1500.0))
    assert r.error_mm == pytest.approx(0.1234)
    assert r.port_status == 0x31 and r.frame == 10
    assert not (r.missing or r.out_of_volume or r.partially_out_of_volume)
    expected = np.array([[1, 0, 0, 10.5], [0, 1, 0, -20.25], [0, 0, 1, -1500.0], [0, 0, 0, 1]])
    np.testing.assert_allclose(r.pose, expected, atol=1e-12)
    assert tx.frame == 10


def test_encode_tx_reproduces_sheet_example() -> None:
    rec = p.HandleRecord.valid(1, (1, 0, 0, 0), (10.5, -20.25, -1500.0), 0.1234, 0x31, 10)
    assert p.encode_tx([rec], 0) == SHEET_TX
    assert p.frame_reply(SHEET_TX).endswith(b"\r")


def test_tx_rotation_hand_computed() -> None:
    # 90° about z: q = (cos 45°, 0, 0, sin 45°) -> x axis maps to y
    row = "03+07071+00000+00000+07071-000100+000250-120000+00500000000B100000064\n"
    tx = p.decode_tx("01" + row + "0002")
    (r,) = tx.records
    R = r.pose[:3, :3]
    np.testing.assert_allclose(R, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-4)
    np.testing.assert_allclose(r.pose[:3, 3], [-1.0, 2.5, -1200.0])
    assert r.error_mm == pytest.approx(0.05)
    assert r.port_status == 0xB1 and r.partially_out_of_volume and not r.out_of_volume
    assert r.frame == 0x64 and tx.system_status == 2


def test_tx_missing_and_out_of_volume_rows() -> None:
    payload = ("02" "01MISSING000000710000002A\n"
               "02+10000+00000+00000+00000+000000+000000-200000+00000000000710000002A\n"
               "0000")
    tx = p.decode_tx(payload)
    a, b = tx.records
    assert a.missing and a.pose is None and a.out_of_volume and a.frame == 42
    assert not b.missing and b.out_of_volume and b.pose is not None
    assert p.encode_tx(tx.records, 0) == payload


def test_tx_disabled_rows_are_read_but_never_written() -> None:
    tx = p.decode_tx("0101DISABLED\n0000")
    assert tx.records[0].status == "disabled" and tx.frame is None
    assert p.encode_tx(tx.records) == "000000"


def test_encode_tx_signs_and_clamps() -> None:
    rec = p.HandleRecord.valid(1, (0.5, -0.5, 0.5, -0.5), (12345.678, -0.004, 0.0), 20.0, 0x31,
                               1)
    row = p.encode_tx([rec]).split("\n")[0][4:]
    assert row.startswith("+05000-05000+05000-05000+999999+000000+000000+99999")


@pytest.mark.parametrize("payload", [
    "",
    "02" + SHEET_TX[2:],                       # count says 2, one row
    SHEET_TX.replace("+10000", "10000+", 1),   # sign in the wrong place
    SHEET_TX[:-1],                             # system status 3 digits
    "0101+00000+00000+00000+00000+000000+000000+000000+00000000000310000000A\n0000",  # q = 0
    "0101GARBAGE\n0000",
])
def test_bad_tx_payloads(payload: str) -> None:
    with pytest.raises(ProtocolError):
        p.decode_tx(payload)


# --- BX -----------------------------------------------------------------------------------------

def _sheet_bx() -> bytes:
    """The sheet's 53-byte example, built by hand: header c4 a5 2d 00 + header CRC 30 43,
    one valid handle with the TX example's values, system status 0, body CRC fc 62."""
    body = bytes([1, 1, 0x01]) + struct.pack("<8f", 1, 0, 0, 0, 10.5, -20.25, -1500.0, 0.1234)
    body += struct.pack("<IIH", 0x31, 10, 0)
    return bytes.fromhex("c4a52d003043") + body + bytes.fromhex("fc62")


def test_bx_golden_example() -> None:
    raw = _sheet_bx()
    assert len(raw) == 53 and raw[:9] == bytes.fromhex("c4a52d0030430101 01".replace(" ", ""))
    bx = p.decode_bx(raw)
    (r,) = bx.records
    assert (r.handle, r.status, r.port_status, r.frame) == (1, "valid", 0x31, 10)
    np.testing.assert_allclose(r.translation_mm, (10.5, -20.25, -1500.0))
    assert r.error_mm == pytest.approx(0.1234, abs=1e-6)
    np.testing.assert_allclose(r.pose[:3, :3], np.eye(3))
    rec = p.HandleRecord.valid(1, (1, 0, 0, 0), (10.5, -20.25, -1500.0), 0.1234, 0x31, 10)
    assert p.encode_bx([rec], 0) == raw


def test_bx_missing_and_disabled() -> None:
    body = bytes([2, 3, 0x02]) + struct.pack("<II", 0x31, 7) + bytes([4, 0x04])
    body += struct.pack("<H", 0x0202)
    head = struct.pack("<HH", 0xA5C4, len(body))
    raw = head + struct.pack("<H", p.crc16(head)) + body + struct.pack("<H", p.crc16(body))
    bx = p.decode_bx(raw)
    a, b = bx.records
    assert a.missing and a.handle == 3 and a.frame == 7 and a.port_status == 0x31
    assert b.status == "disabled" and bx.system_status == 0x0202
    assert p.encode_bx(bx.records, 0x0202) == raw


@pytest.mark.parametrize("mutate", [
    lambda b: b[:-1],                                  # torn
    lambda b: b[:-1] + bytes([b[-1] ^ 1]),             # body CRC
    lambda b: b[:4] + bytes([b[4] ^ 1]) + b[5:],       # header CRC
    lambda b: b"\xc5" + b[1:],                         # start sequence
    lambda b: b + b"\x00",                             # trailing byte
])
def test_bad_bx(mutate) -> None:
    with pytest.raises(ProtocolError):
        p.decode_bx(mutate(_sheet_bx()))


def test_bx_unknown_handle_status() -> None:
    body = bytes([1, 1, 0x08]) + struct.pack("<H", 0)
    head = struct.pack("<HH", 0xA5C4, len(body))
    raw = head + struct.pack("<H", p.crc16(head)) + body + struct.pack("<H", p.crc16(body))
    with pytest.raises(ProtocolError, match="unknown status"):
        p.decode_bx(raw)


def test_reply_length() -> None:
    bx = _sheet_bx()
    assert p.reply_length(b"") is None
    assert p.reply_length(b"OKAY") is None
    assert p.reply_length(b"OKAYA896\rxx") == 9
    assert p.reply_length(bx[:1]) is None
    assert p.reply_length(bx[:5]) is None
    assert p.reply_length(bx[:6]) == 53
    with pytest.raises(ProtocolError):
        p.reply_length(b"\xc4\xa5\x2d\x00\x30\x44")
    with pytest.raises(ProtocolError):
        p.reply_length(b"\xc4\x00")
    with pytest.raises(ProtocolError):
        p.reply_length(b"A" * (p.MAX_TEXT_REPLY + 1))


def test_pose_round_trip_through_record() -> None:
    from tmscal.geometry import make_pose, random_rotation
    T = make_pose(random_rotation(np.random.default_rng(0)), [12.0, -3.5, -1400.25])
    rec = p.HandleRecord.from_pose(2, T, 0.2, 0x31, 5)
    back = p.decode_bx(p.encode_bx([rec])).records[0]
    np.testing.assert_allclose(back.pose, T, atol=2e-4)  # float32
    back = p.decode_tx(p.encode_tx([rec])).records[0]
    np.testing.assert_allclose(back.pose[:3, 3], T[:3, 3], atol=0.005)
    np.testing.assert_allclose(back.pose[:3, :3], T[:3, :3], atol=3e-4)


# --- handle management --------------------------------------------------------------------------

def test_phsr_round_trip_hand_built() -> None:
    assert p.decode_phsr("020103120001") == [(1, 0x031), (0x20, 0x001)]
    assert p.encode_phsr({1: 0x031, 0x20: 0x001}) == "020103120001"
    assert p.decode_phsr("00") == []
    for bad in ("", "01", "0101", "0201031200", "01zz031"):
        with pytest.raises(ProtocolError):
            p.decode_phsr(bad)


def test_phrq_and_pvwr() -> None:
    assert p.decode_phrq("0A") == 10
    with pytest.raises(ProtocolError):
        p.decode_phrq("A")
    chunks = p.rom_chunks(bytes(range(256)) * 2 + b"\x01" * 88)  # 600 bytes
    assert [a for a, _ in chunks] == list(range(0, 640, 64))
    assert chunks[-1][1][-40:] == bytes(40)
    assert len(p.rom_chunks(b"\x01", pad_to=1024)) == 16
    prm = p.pvwr_params(1, 0x3C0, bytes([0xAB]) * 64)
    assert prm == "0103C0" + "AB" * 64
    assert p.crc_hex("PVWR:" + prm) == p.encode_command("PVWR", prm)[-5:-1].decode()


def test_parse_ver() -> None:
    v = p.parse_ver("Polaris Spectra Control Firmware\nFreeze Tag: Polaris Spectra Rev 007\n"
                    "Serial Number: P6-01234\n")
    assert v["title"] == "Polaris Spectra Control Firmware"
    assert v["Freeze Tag"] == "Polaris Spectra Rev 007"
    assert v["Serial Number"] == "P6-01234"
