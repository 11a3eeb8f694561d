"""NDI Combined API codec (Polaris Vicra / Spectra): both directions, one import.

Used by the driver (:mod:`tmscal.drivers.ndi.tracker`) to encode commands and decode replies,
and by the mock (:mod:`tmscal.mocks.polaris`) to decode commands and encode replies, so the
two can never disagree on a layout. Facts: NDI's Polaris Application Program Interface Guide
(Combined API). The codec lives in small modules; this one re-exports their names:

* :mod:`.crc`: CRC-16/ARC (poly 0x8005 reflected, init 0, no final XOR), :func:`crc16`.
* :mod:`.codes`: ``ERRORxx`` / ``WARNINGxx`` meanings (:class:`ErrorCode`), the status
  words as ``IntFlag`` s (:class:`PortStatus`, :class:`SystemStatus`, :class:`HandleStatus`,
  :class:`ToolInfoStatus`), :class:`ReplyOption`, the COMM baud codes.
* :mod:`.commands`: ``CMD:params`` + 4 uppercase hex CRC + ``\\r`` (colon form) or
  ``CMD params\\r`` (space form, no CRC): :func:`encode_command`, :func:`parse_command`.
* :mod:`.replies`: text + 4 hex CRC + ``\\r`` (:func:`frame_reply`, :func:`parse_reply`,
  :class:`ReplyKind`); :func:`reply_length` finds where the first complete reply (text or
  BX) in a byte buffer ends; PHSR / PHRQ / VER payloads.
* :mod:`.tracking`: TX and BX (:func:`encode_tx`, :func:`decode_tx`, :func:`encode_bx`,
  :func:`decode_bx`): per port handle a :class:`HandleRecord` with the pose
  ``tracker_from_tool`` as a 4×4 matrix in mm, the RMS fit error in mm, the port status word
  and the 32-bit frame number; plus the system status word.

Errors: :class:`~tmscal.errors.ProtocolError` for bytes that do not parse (bad framing, CRC
mismatch, torn or malformed replies; the message quotes what was received);
:class:`~tmscal.errors.DeviceError` with ``code`` (int NDI error code) and ``text`` (its
meaning) for ``ERRORxx`` replies.
"""

from __future__ import annotations

from .codes import (
    BAUD_CODES,
    BAUD_FROM_CODE,
    DEVICE,
    ERROR_TEXTS,
    PORT_HEALTHY,
    WARNING_TEXTS,
    BxStatus,
    ErrorCode,
    HandleStatus,
    PortStatus,
    ReplyOption,
    SystemStatus,
    ToolInfoStatus,
    error_text,
    flag_names,
    warning_text,
)
from .commands import Command, encode_command, parse_command, pvwr_params, rom_chunks
from .crc import crc16, crc_hex
from .replies import (
    BX_START,
    BX_START_BYTES,
    MAX_TEXT_REPLY,
    OKAY_REPLY,
    RESET_REPLY,
    Reply,
    ReplyKind,
    classify_reply,
    decode_phrq,
    decode_phsr,
    encode_error,
    encode_phsr,
    encode_warning,
    frame_reply,
    is_bx,
    parse_hex,
    parse_reply,
    parse_ver,
    raise_for_error,
    reply_length,
    split_reply,
)
from .tracking import (
    HandleRecord,
    RecordStatus,
    TrackingReply,
    check_bx,
    decode_bx,
    decode_tx,
    encode_bx,
    encode_tx,
    records_from_poses,
)

__all__ = [
    "crc16", "crc_hex", "DEVICE", "ERROR_TEXTS", "WARNING_TEXTS", "error_text", "warning_text",
    "ErrorCode", "PortStatus", "SystemStatus", "HandleStatus", "ToolInfoStatus", "ReplyOption",
    "BxStatus",
    "PORT_HEALTHY", "flag_names", "BAUD_CODES", "BAUD_FROM_CODE",
    "encode_command", "parse_command", "Command", "pvwr_params", "rom_chunks",
    "frame_reply", "reply_length", "ReplyKind", "Reply", "split_reply", "classify_reply",
    "parse_reply", "raise_for_error", "encode_error", "encode_warning", "OKAY_REPLY",
    "RESET_REPLY", "MAX_TEXT_REPLY", "BX_START", "BX_START_BYTES", "is_bx", "parse_hex",
    "encode_phsr", "decode_phsr", "decode_phrq", "parse_ver",
    "RecordStatus", "HandleRecord", "TrackingReply", "records_from_poses", "decode_tx",
    "encode_tx", "encode_bx", "decode_bx", "check_bx",
]
