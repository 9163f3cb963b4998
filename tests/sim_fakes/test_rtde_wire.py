"""The RTDE wire format of the fake UR (sim_fakes/rtde_wire.py): exact bytes of messages, recipes and replies."""

from __future__ import annotations

import struct

import pytest

from sim_fakes import rtde_wire as wire


def test_a_message_is_its_size_with_the_header_its_type_and_its_payload() -> None:
    assert wire.pack_message(wire.MsgType.CONTROL_PACKAGE_START) == b"\x00\x03S"
    assert wire.pack_message(wire.MsgType.REQUEST_PROTOCOL_VERSION, b"\x00\x02") == b"\x00\x05V\x00\x02"
    big = wire.pack_message(wire.MsgType.DATA_PACKAGE, bytes(300))
    assert big[:3] == b"\x01\x2fU" and len(big) == 303  # 303 = 0x012f, big-endian


def test_output_types_follow_the_guide_and_version_gates_hide_the_newer_ones() -> None:
    cb3, e_series_old, e_series = (3, 15, 8, 1), (5, 5, 0, 1), (5, 23, 0, 1)
    assert wire.output_type("actual_TCP_pose", cb3) == "VECTOR6D"
    assert wire.output_type("robot_mode", cb3) == "INT32"
    assert wire.output_type("output_int_register_47", cb3) == "INT32"
    assert wire.output_type("output_int_register_48", cb3) == wire.NOT_FOUND  # 0..47 only
    assert wire.output_type("output_bit_register_64", cb3) == "BOOL"
    assert wire.output_type("output_bit_register_63", cb3) == wire.NOT_FOUND  # 64..127 only
    assert wire.output_type("no_such_variable", cb3) == wire.NOT_FOUND
    # payload from 3.11 / 5.5.1; the torque currents from 5.23 only, never on a CB3
    assert [wire.output_type("payload", v) for v in ((3, 10, 9, 0), cb3, e_series_old, (5, 5, 1, 0))] == [
        wire.NOT_FOUND, "DOUBLE", wire.NOT_FOUND, "DOUBLE",
    ]  # fmt: skip
    assert [wire.output_type("actual_current_as_torque", v) for v in (cb3, (5, 22, 9, 0), e_series)] == [
        wire.NOT_FOUND, wire.NOT_FOUND, "VECTOR6D",
    ]  # fmt: skip
    assert len(wire.OUTPUT_TYPES) == 63 + 4 * 48 + 2 * 64  # 63 named, int and double registers 0..47, bits 64..127
    assert len(wire.INPUT_TYPES) == 15 + 2 * 48 + 64


def test_an_output_recipe_packs_a_data_package_in_its_order_and_types() -> None:
    names = ("timestamp", "actual_q", "robot_mode", "actual_digital_output_bits", "output_bit_register_64")
    recipe = wire.Recipe.build(3, names, [wire.OUTPUT_TYPES[n] for n in names], frequency_hz=125.0)
    assert recipe.valid and recipe.layout.format == ">Bd6diQ?" and recipe.frequency_hz == 125.0
    q = (0.0, -1.57, 1.57, -1.57, -1.57, 0.0)
    values = {"timestamp": 12.5, "actual_q": q, "robot_mode": 7, "actual_digital_output_bits": 1 << 5}
    msg = recipe.pack({**values, "output_bit_register_64": True, "ignored": 1})
    body = struct.pack(">Bd6diQ?", 3, 12.5, *q, 7, 32, True)
    assert msg == struct.pack(">HB", 3 + len(body), ord("U")) + body
    assert len(body) == 1 + 8 + 48 + 4 + 8 + 1


def test_an_input_recipe_unpacks_a_clients_data_package_and_ignores_trailing_bytes() -> None:
    names = ["standard_digital_output_mask", "standard_digital_output", "external_force_torque"]
    recipe = wire.Recipe.build(1, names, [wire.INPUT_TYPES[n] for n in names])
    wrench = (1.0, 2.0, 3.0, 0.1, 0.2, 0.3)
    payload = struct.pack(">BBB6d", 1, 0b0001, 0b0001, *wrench) + b"\xff\xff"
    assert recipe.unpack(payload) == {
        "standard_digital_output_mask": 1,
        "standard_digital_output": 1,
        "external_force_torque": wrench,
    }


def test_a_recipe_with_an_unknown_name_is_invalid_and_answers_not_found_in_its_place() -> None:
    types = ["DOUBLE", wire.NOT_FOUND]
    recipe = wire.Recipe.build(0, ["timestamp", "bogus"], types)
    assert not recipe.valid and recipe.layout.format == ">Bd"  # the unknown type packs nothing
    assert wire.setup_reply(recipe) == b"\x00DOUBLE,NOT_FOUND"
    good = wire.Recipe.build(2, ["speed_slider_mask", "speed_slider_fraction"], ["UINT32", "DOUBLE"])
    assert wire.setup_reply(good) == b"\x02UINT32,DOUBLE"


def test_names_are_comma_separated_with_blanks_and_a_trailing_comma_dropped() -> None:
    assert wire.parse_names(b"timestamp, actual_q,robot_mode,") == ["timestamp", "actual_q", "robot_mode"]
    assert wire.parse_names(b"") == []
    assert wire.parse_names(b"a,\xff,b") == ["a", "\ufffd", "b"]  # bad bytes become replacement characters


def test_a_text_message_carries_its_text_source_and_level_with_their_lengths() -> None:
    msg = wire.text_message(2, "slow", source="fake")
    assert msg == b"\x00\x0eM" + b"\x04slow" + b"\x04fake" + b"\x02"
    long = wire.text_message(3, "x" * 300)
    assert long[3] == 255 and long[4 : 4 + 255] == b"x" * 255  # cut to a byte's length
    assert long[-9:] == b"\x07fake_ur\x03"
    assert struct.unpack(">H", long[:2])[0] == len(long)


@pytest.mark.parametrize(("rtde_type", "count"), [("VECTOR3D", 3), ("VECTOR6INT32", 6), ("UINT8", 1)])
def test_every_type_code_packs_as_many_scalars_as_it_says(rtde_type: str, count: int) -> None:
    code, n = wire.TYPE_CODES[rtde_type]
    assert n == count and len(struct.unpack(">" + code, bytes(struct.calcsize(">" + code)))) == count
