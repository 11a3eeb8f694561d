"""The RTDE wire codec (Universal Robots Real-Time Data Exchange, protocol version 2) as the
UR mock speaks it: package framing, package types, the variable type table, recipes.

A package is ``size`` (uint16, big-endian, header included), ``type`` (uint8, an ASCII
letter) and a payload. Recipes name controller variables, comma-separated; each variable has
an RTDE type (``DOUBLE``, ``VECTOR6D``, …) and is packed big-endian in recipe order after a
one-byte recipe id. Names and layout follow UR's "Real-Time Data Exchange (RTDE) Guide" and
its Python client library (whose ``serialize.py`` holds the codec apart from the connection,
as this module does). Nothing here touches a socket except ``recv_exact``.
"""

from __future__ import annotations

import re
import socket
import struct
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

__all__ = [
    "HEADER", "PROTOCOL_VERSIONS", "TYPES", "PackageType", "Recipe", "encode_package",
    "parse_names", "recv_exact", "rtde_type", "zero_value",
]

#: Package header: size (header included) and type.
HEADER = struct.Struct(">HB")
#: Protocol versions the mock accepts (``RTDE_REQUEST_PROTOCOL_VERSION``).
PROTOCOL_VERSIONS = (1, 2)
#: Payload of ``RTDE_REQUEST_PROTOCOL_VERSION`` (uint16) and of the controller version reply
#: (major, minor, bugfix, build as uint32).
PROTOCOL_VERSION = struct.Struct(">H")
CONTROLLER_VERSION = struct.Struct(">IIII")
#: Leading field of ``RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS``: the output frequency (Hz).
OUTPUT_FREQUENCY = struct.Struct(">d")


class PackageType(IntEnum):
    """RTDE package types (the ASCII letter on the wire in the comment)."""

    RTDE_REQUEST_PROTOCOL_VERSION = 86       # 'V'
    RTDE_GET_URCONTROL_VERSION = 118         # 'v'
    RTDE_TEXT_MESSAGE = 77                   # 'M'
    RTDE_DATA_PACKAGE = 85                   # 'U'
    RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS = 79  # 'O'
    RTDE_CONTROL_PACKAGE_SETUP_INPUTS = 73   # 'I'
    RTDE_CONTROL_PACKAGE_START = 83          # 'S'
    RTDE_CONTROL_PACKAGE_PAUSE = 80          # 'P'


#: RTDE type name → (struct code of one value, number of values).
TYPES: dict[str, tuple[str, int]] = {
    "BOOL": ("?", 1), "UINT8": ("B", 1), "UINT32": ("I", 1), "UINT64": ("Q", 1),
    "INT32": ("i", 1), "DOUBLE": ("d", 1), "VECTOR3D": ("d", 3), "VECTOR6D": ("d", 6),
    "VECTOR6INT32": ("i", 6), "VECTOR6UINT32": ("I", 6),
}

# --- which variable has which type (names as in the RTDE guide) -------------------------------

_VECTOR6D = {
    "target_q", "target_qd", "target_qdd", "target_current", "target_moment", "actual_q",
    "actual_qd", "actual_qdd", "actual_current", "actual_current_as_torque",
    "actual_current_window", "joint_control_output", "actual_TCP_pose", "actual_TCP_speed",
    "actual_TCP_force", "target_TCP_pose", "target_TCP_speed", "joint_temperatures",
    "actual_joint_voltage", "ft_raw_wrench", "payload_inertia", "tcp_offset",
    "external_force_torque", "joint_position_deviation_ratio", "collision_detection_ratio",
}
_VECTOR3D = {"actual_tool_accelerometer", "payload_cog", "elbow_position", "elbow_velocity"}
_VECTOR6INT32 = {"joint_mode"}
_INT32 = {"robot_mode", "safety_mode", "safety_status", "tool_output_voltage",
          "tool_analog_output_types"}
_UINT32 = {"runtime_state", "robot_status_bits", "safety_status_bits", "tool_mode",
           "analog_io_types", "tool_analog_input_types", "output_bit_registers0_to_31",
           "output_bit_registers32_to_63", "input_bit_registers0_to_31",
           "input_bit_registers32_to_63", "euromap67_input_bits", "euromap67_output_bits",
           "script_control_line"}
_UINT64 = {"actual_digital_input_bits", "actual_digital_output_bits"}
_UINT8 = {"tool_output_mode", "tool_digital_output0_mode", "tool_digital_output1_mode",
          "standard_digital_output_mask", "standard_digital_output",
          "configurable_digital_output_mask", "configurable_digital_output",
          "tool_digital_output_mask", "tool_digital_output", "standard_analog_output_mask",
          "standard_analog_output_type", "speed_slider_mask"}
_INT_REGISTER = re.compile(r"(input|output)_int_register_\d+")
_BIT_REGISTER = re.compile(r"(input|output)_bit_register_\d+")

#: Named variables by type, checked in this order (the register patterns in ``rtde_type``).
_BY_TYPE: tuple[tuple[set[str], str], ...] = (
    (_VECTOR6D, "VECTOR6D"), (_VECTOR3D, "VECTOR3D"), (_VECTOR6INT32, "VECTOR6INT32"),
    (_INT32, "INT32"), (_UINT32, "UINT32"), (_UINT64, "UINT64"), (_UINT8, "UINT8"),
)


def rtde_type(name: str) -> str:
    """The RTDE type name of a variable (``DOUBLE`` for names this mock does not know)."""
    for names, type_name in _BY_TYPE:
        if name in names:
            return type_name
    if _INT_REGISTER.fullmatch(name):
        return "INT32"
    if _BIT_REGISTER.fullmatch(name):
        return "BOOL"
    return "DOUBLE"


def zero_value(type_name: str) -> Any:
    """The zero of an RTDE type: 0.0, False or 0, or a list of them for a vector type."""
    code, count = TYPES[type_name]
    zero: Any = 0.0 if code == "d" else False if code == "?" else 0
    return [zero] * count if count > 1 else zero


def parse_names(payload: bytes) -> list[str]:
    """Variable names from a recipe request (comma-separated ASCII; empty names dropped)."""
    return [n for n in payload.decode("ascii", "replace").split(",") if n]


@dataclass(frozen=True)
class Recipe:
    """An output or input recipe: variable names, their RTDE types, and the struct of a
    data package (recipe id byte first)."""

    names: tuple[str, ...]
    types: tuple[str, ...]
    packer: struct.Struct

    @classmethod
    def from_names(cls, names: Iterable[str]) -> Recipe:
        names = tuple(names)
        types = tuple(rtde_type(n) for n in names)
        fields = "".join(_field_format(t) for t in types)
        return cls(names, types, struct.Struct(">B" + fields))

    @property
    def vectors(self) -> tuple[bool, ...]:
        """Per variable, whether it packs several values (a vector type)."""
        return tuple(TYPES[t][1] > 1 for t in self.types)

    def setup_reply(self, recipe_id: int) -> bytes:
        """The payload answering a setup request: recipe id, then the types comma-separated."""
        return bytes([recipe_id & 0xFF]) + ",".join(self.types).encode()

    def pack(self, recipe_id: int, values: Sequence[Any]) -> bytes:
        """A data package payload from one value (a list for vector types) per variable."""
        flat: list[Any] = [recipe_id]
        for v, is_vector in zip(values, self.vectors, strict=True):
            if is_vector:
                flat.extend(v)
            else:
                flat.append(v)
        return self.packer.pack(*flat)

    def unpack(self, payload: bytes) -> list[tuple[str, list[Any]]]:
        """(name, values) per variable of a data package payload (recipe id byte included);
        raises ``struct.error`` when the size is wrong."""
        flat = list(self.packer.unpack(payload))[1:]
        out = []
        for name, t in zip(self.names, self.types, strict=True):
            n = TYPES[t][1]
            out.append((name, flat[:n]))
            flat = flat[n:]
        return out


def _field_format(type_name: str) -> str:
    code, count = TYPES[type_name]
    return f"{count}{code}" if count > 1 else code


def encode_package(ptype: int, payload: bytes = b"") -> bytes:
    """One package on the wire: header (size, type) and payload."""
    return HEADER.pack(HEADER.size + len(payload), ptype) + payload


def recv_exact(sock: socket.socket, n: int, alive: Callable[[], bool]) -> bytes | None:
    """``n`` bytes from ``sock`` (whose timeout is a poll period), or None when the peer
    closed or ``alive()`` turned false."""
    buf = bytearray()
    while len(buf) < n:
        if not alive():
            return None
        try:
            chunk = sock.recv(n - len(buf))
        except TimeoutError:
            continue
        except OSError:
            return None
        if not chunk:
            return None
        buf += chunk
    return bytes(buf)
