"""Property tests of the OpenIGTLink codec and frame assembly (``drivers.igtl``): TRANSFORMs
packed by pyigtl parse back to what was sent; any bytes either parse or fail with the one
typed error; a changed byte never passes the CRC; frames assembled from any interleaving of
fresh and stale transforms are exactly the frames that were sent; any address override parses
or is a ConfigError naming the key."""

from __future__ import annotations

import struct

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from pyigtl.messages import CRC64

from tests.fuzz import fuzz_settings
from tmscal.drivers.igtl import wire
from tmscal.drivers.igtl.frames import FrameAssembler
from tmscal.drivers.igtl.settings import IGTLSettings
from tmscal.errors import ConfigError, ProtocolError

names = st.text(st.characters(min_codepoint=0x21, max_codepoint=0x7E), min_size=1,
                max_size=wire.MAX_NAME_BYTES)
stamps = st.integers(0, 2**64 - 1)
f32 = st.floats(-1e6, 1e6, allow_nan=False, width=32)
meta_text = st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E), max_size=30)


def _header(version: int, mtype: bytes, device: bytes, stamp: int, body: bytes,
            crc: int | None = None) -> bytes:
    return struct.pack(">H12s20sQQQ", version, mtype, device, stamp, len(body),
                       CRC64(body) if crc is None else crc)


@fuzz_settings()
@given(names, st.lists(f32, min_size=12, max_size=12), stamps, st.sampled_from([1, 2]),
       st.dictionaries(st.text(st.characters(min_codepoint=0x21, max_codepoint=0x7E),
                               min_size=1, max_size=20), meta_text, max_size=4))
def test_transform_round_trip(device: str, values: list[float], stamp: int, version: int,
                              meta: dict[str, str]) -> None:
    m = np.eye(4)
    m[:3, :] = np.array(values).reshape(4, 3).T   # rotation columns, then the translation
    data = wire.encode_transform(device, m, stamp=stamp, version=version, metadata=meta)
    h = wire.parse_header(data[:wire.HEADER_SIZE])
    assert (h.version, h.type, h.device, h.stamp) == (version, "TRANSFORM", device, stamp)
    t = wire.decode_transform(h, data[wire.HEADER_SIZE:])
    np.testing.assert_array_equal(t.matrix, m.astype(np.float32))
    assert t.metadata == (meta if version == 2 else {})
    assert t.timestamp == (stamp >> 32) + (stamp & 0xFFFFFFFF) / 2**32


@fuzz_settings()
@given(st.binary(min_size=wire.HEADER_SIZE, max_size=wire.HEADER_SIZE))
def test_any_header_bytes_parse_or_are_a_protocol_error(data: bytes) -> None:
    try:
        h = wire.parse_header(data)
    except ProtocolError:
        return
    assert h.version in (1, 2) and h.body_size <= wire.MAX_BODY_SIZE and h.type.isprintable()


@fuzz_settings(examples=300)
@given(st.sampled_from([1, 2]), st.binary(max_size=200), names)
def test_any_body_with_a_right_crc_decodes_or_is_a_protocol_error(version: int, body: bytes,
                                                                 device: str) -> None:
    data = _header(version, b"TRANSFORM", device.encode(), 7, body)
    h = wire.parse_header(data)
    try:
        t = wire.decode_transform(h, body)
    except ProtocolError:
        return
    assert t.matrix.shape == (4, 4) and t.device == device


@fuzz_settings(examples=300)
@given(st.sampled_from([1, 2]), st.binary(min_size=12, max_size=120), st.data())
def test_version_2_layouts_decode_or_are_a_protocol_error(version: int, tail: bytes,
                                                         data: st.DataObject) -> None:
    """Extended-header and metadata size fields of every value, not only random bytes."""
    ext = struct.pack(">HHII", data.draw(st.integers(0, 40)), data.draw(st.integers(0, 80)),
                      data.draw(st.integers(0, 80)), 0)
    body = ext + tail
    h = wire.parse_header(_header(2, b"TRANSFORM", b"X", 1, body))
    try:
        content, meta, _ = wire.split_body(h, body)
    except ProtocolError:
        return
    assert len(content) <= len(body) and all(isinstance(v, str) for v in meta.values())


@fuzz_settings(examples=300)
@given(names, st.sampled_from([1, 2]), st.data())
def test_a_changed_byte_never_passes_the_crc(device: str, version: int,
                                             data: st.DataObject) -> None:
    msg = bytearray(wire.encode_transform(device, np.eye(4) * 2, stamp=5, version=version,
                                          metadata={"TransformStatus": "OK"}))
    i = data.draw(st.integers(wire.HEADER_SIZE, len(msg) - 1))
    msg[i] ^= data.draw(st.integers(1, 255))
    h = wire.parse_header(bytes(msg[:wire.HEADER_SIZE]))
    try:
        wire.decode_transform(h, bytes(msg[wire.HEADER_SIZE:]))
    except ProtocolError as e:
        assert "CRC mismatch" in str(e)
    else:
        raise AssertionError("a corrupted body passed the CRC")


# --- frames -----------------------------------------------------------------------------------

TOOLS = {"marker": "M", "probe": "P"}
#: per frame, which tools the source sent
frame_lists = st.lists(st.tuples(st.booleans(), st.booleans()), min_size=1, max_size=30)


@fuzz_settings()
@given(frame_lists, st.randoms(use_true_random=False), st.booleans())
def test_assembled_frames_are_the_frames_sent(sent: list[tuple[bool, bool]], rnd,
                                              stale_noise: bool) -> None:
    """Frames of increasing timestamps, each frame's transforms in any order, stale repeats
    of older transforms anywhere after them: every frame that carried a transform is
    delivered once, in order, each tool present exactly when it was sent in that frame."""
    msgs: list[wire.Transform] = []
    expected: list[tuple[bool, bool]] = []
    for k, (m, p) in enumerate(sent):
        stamp = 1000 + k
        pose = np.eye(4)
        pose[:3, 3] = [k, 1.0, -1500.0]
        devs = ["M"] * m + ["P"] * p + ["Other"] * (not (m or p))   # every frame marks time
        rnd.shuffle(devs)
        for d in devs:
            msgs.append(wire.Transform(d, stamp, float(stamp), pose))
            if stale_noise and k > 0 and rnd.random() < 0.5:
                msgs.append(wire.Transform(rnd.choice("MP"), stamp - rnd.randint(1, k),
                                           0.0, np.eye(4) * 3))
        expected.append((m, p))
    a = FrameAssembler(TOOLS)
    got = [fr for i, t in enumerate(msgs) for fr in a.feed(t, float(i))]
    # the last frame is delivered when complete; else it is still open
    assert len(got) in (len(sent) - 1, len(sent))
    assert [f.frame for f in got] == list(range(len(got)))
    for k, fr in enumerate(got):
        assert (fr.tools["marker"].usable, fr.tools["probe"].usable) == expected[k]
        for tool in ("marker", "probe"):
            pose = fr.pose(tool)
            assert pose is None or pose[0, 3] == k


@fuzz_settings()
@given(st.text(max_size=40))
def test_any_address_override_parses_or_is_a_config_error(text: str) -> None:
    s = IGTLSettings("10.0.0.5", 18944, tools={"marker": "M"}, src="rig.yaml")
    try:
        out = s.with_address(text)
    except ConfigError as e:
        assert "key 'tracker.host'" in str(e) or "key 'tracker.port'" in str(e)
        return
    assert out.host and 1 <= out.port <= 65535 and out.tools == s.tools
    if ":" not in text:   # a host alone keeps the port
        assert out.host == text and out.port == 18944
