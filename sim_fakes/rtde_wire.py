"""The RTDE wire format (protocol version 2) as a UR controller serves it on TCP port 30004.

Every message is ``uint16 size`` (header included, big-endian) + ``uint8 type`` + payload. The client negotiates
the protocol version, asks the controller version, sets up output recipes (a frequency and variable names; the
controller answers a recipe id and the variable types) and input recipes (names; id and types), then starts
synchronisation: the controller streams one data package per output recipe per cycle, and the client sends data
packages that write input variables. Unknown names are answered with ``NOT_FOUND``.

Variable names and types follow Universal Robots' RTDE guide. Only the fake controller uses this module.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

HEADER = struct.Struct(">HB")
PROTOCOL_VERSIONS = (1, 2)


class MsgType(IntEnum):
    REQUEST_PROTOCOL_VERSION = ord("V")
    GET_URCONTROL_VERSION = ord("v")
    TEXT_MESSAGE = ord("M")
    DATA_PACKAGE = ord("U")
    CONTROL_PACKAGE_SETUP_OUTPUTS = ord("O")
    CONTROL_PACKAGE_SETUP_INPUTS = ord("I")
    CONTROL_PACKAGE_START = ord("S")
    CONTROL_PACKAGE_PAUSE = ord("P")


# struct codes of the RTDE types, and how many scalars each holds
TYPE_CODES: dict[str, tuple[str, int]] = {
    "BOOL": ("?", 1),
    "UINT8": ("B", 1),
    "UINT32": ("I", 1),
    "UINT64": ("Q", 1),
    "INT32": ("i", 1),
    "DOUBLE": ("d", 1),
    "VECTOR3D": ("3d", 3),
    "VECTOR6D": ("6d", 6),
    "VECTOR6INT32": ("6i", 6),
    "VECTOR6UINT32": ("6I", 6),
}

NOT_FOUND = "NOT_FOUND"

_V6 = "VECTOR6D"
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE",
    "target_q": _V6,
    "target_qd": _V6,
    "target_qdd": _V6,
    "target_current": _V6,
    "target_moment": _V6,
    "actual_q": _V6,
    "actual_qd": _V6,
    "actual_current": _V6,
    "joint_control_output": _V6,
    "actual_TCP_pose": _V6,
    "actual_TCP_speed": _V6,
    "actual_TCP_force": _V6,
    "target_TCP_pose": _V6,
    "target_TCP_speed": _V6,
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": _V6,
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": _V6,
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "payload_inertia": _V6,
    "script_control_line": "UINT32",
    "ft_raw_wrench": _V6,
    "joint_position_deviation_ratio": "DOUBLE",
    "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "UINT32",
    "actual_current_as_torque": _V6,
}
for _i in range(48):
    OUTPUT_TYPES[f"output_int_register_{_i}"] = "INT32"
    OUTPUT_TYPES[f"output_double_register_{_i}"] = "DOUBLE"
    OUTPUT_TYPES[f"input_int_register_{_i}"] = "INT32"
    OUTPUT_TYPES[f"input_double_register_{_i}"] = "DOUBLE"
for _i in range(64, 128):
    OUTPUT_TYPES[f"output_bit_register_{_i}"] = "BOOL"
    OUTPUT_TYPES[f"input_bit_register_{_i}"] = "BOOL"

# outputs that only exist from some controller versions on: name -> {major: minimum (minor, bugfix)}
OUTPUT_MIN_VERSION: dict[str, dict[int, tuple[int, int]]] = {
    "payload": {3: (11, 0), 5: (5, 1)},
    "payload_cog": {3: (11, 0), 5: (5, 1)},
    "payload_inertia": {3: (15, 0), 5: (11, 0)},
    "ft_raw_wrench": {5: (9, 0)},
    "actual_current_as_torque": {5: (23, 0)},
}

INPUT_TYPES: dict[str, str] = {
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": _V6,
}
for _i in range(48):
    INPUT_TYPES[f"input_int_register_{_i}"] = "INT32"
    INPUT_TYPES[f"input_double_register_{_i}"] = "DOUBLE"
for _i in range(64, 128):
    INPUT_TYPES[f"input_bit_register_{_i}"] = "BOOL"


def output_type(name: str, version: tuple[int, int, int, int]) -> str:
    """RTDE type of output ``name`` on a controller of ``version``, or ``NOT_FOUND``."""
    rtde_type = OUTPUT_TYPES.get(name)
    if rtde_type is None:
        return NOT_FOUND
    gate = OUTPUT_MIN_VERSION.get(name)
    if gate is not None:
        minimum = gate.get(version[0])
        if minimum is None or (version[1], version[2]) < minimum:
            return NOT_FOUND
    return rtde_type


def pack_message(msg_type: int, payload: bytes = b"") -> bytes:
    return HEADER.pack(HEADER.size + len(payload), msg_type) + payload


@dataclass(frozen=True)
class Recipe:
    """One output or input recipe: its id, variable names, types and the struct that packs them."""

    recipe_id: int
    names: tuple[str, ...]
    types: tuple[str, ...]
    layout: struct.Struct
    frequency_hz: float = 0.0

    @classmethod
    def build(cls, recipe_id: int, names: Sequence[str], types: Sequence[str], frequency_hz: float = 0.0) -> Recipe:
        fmt = ">B" + "".join(TYPE_CODES[t][0] for t in types if t in TYPE_CODES)
        return cls(recipe_id, tuple(names), tuple(types), struct.Struct(fmt), frequency_hz)

    @property
    def valid(self) -> bool:
        return self.recipe_id > 0

    def pack(self, values: dict[str, Any]) -> bytes:
        """A data package message carrying ``values[name]`` for every name of this output recipe."""
        flat: list[Any] = [self.recipe_id]
        for name, rtde_type in zip(self.names, self.types, strict=True):
            value = values[name]
            if TYPE_CODES[rtde_type][1] == 1:
                flat.append(value)
            else:
                flat.extend(value)
        return pack_message(MsgType.DATA_PACKAGE, self.layout.pack(*flat))

    def unpack(self, payload: bytes) -> dict[str, Any]:
        """Variables of an input data package ``payload`` (recipe id byte included)."""
        flat = self.layout.unpack(payload[: self.layout.size])
        out: dict[str, Any] = {}
        pos = 1
        for name, rtde_type in zip(self.names, self.types, strict=True):
            count = TYPE_CODES[rtde_type][1]
            out[name] = flat[pos] if count == 1 else tuple(flat[pos : pos + count])
            pos += count
        return out


def parse_names(payload: bytes) -> list[str]:
    """Comma-separated variable names (clients may leave a trailing comma)."""
    return [n.strip() for n in payload.decode("ascii", errors="replace").split(",") if n.strip()]


def setup_reply(recipe: Recipe) -> bytes:
    return bytes([recipe.recipe_id]) + ",".join(recipe.types).encode("ascii")


def text_message(level: int, message: str, source: str = "fake_ur") -> bytes:
    """A protocol-v2 text message (``level``: 0 exception, 1 error, 2 warning, 3 info)."""
    msg = message.encode("utf-8")[:255]
    src = source.encode("ascii")[:255]
    return pack_message(MsgType.TEXT_MESSAGE, bytes([len(msg)]) + msg + bytes([len(src)]) + src + bytes([level]))
