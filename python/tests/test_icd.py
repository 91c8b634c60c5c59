"""The ICD as data: typed encoding checked against the ICD's ranges, decoding."""

from __future__ import annotations

import re
import struct

import pytest

from m6p.icd import Icd, IcdError, parse_duration_s

ICD = Icd.load()


def test_every_commands_example_decodes_and_encodes_back_to_the_same_bytes() -> None:
    checked = 0
    for c in ICD.commands():
        if c.example is None or not c.request.described:
            continue
        request = bytes([c.id]) + c.example
        args = c.decode_request(request)
        if c.request.tail is not None:
            assert isinstance(args[c.request.tail.name], bytes), c.full_name
        assert c.encode(**args) == request, c.full_name
        checked += 1
    assert checked >= 19


def test_a_setup_encodes_with_durations_and_names_as_the_icd_lays_it_out() -> None:
    setup = ICD.command("pc.setup")
    b = setup.encode(
        session_id=1,
        timestamp="now",
        duration_s="3m",
        max_packets="no limit",
        poll_frame_size=200,
        sync_message="go",
    )
    assert b == bytes([1, 1]) + struct.pack("<IHHB", 0, 180, 0, 200) + b"go"


def test_a_1000_s_setup_is_refused_naming_the_field_and_the_icd_range() -> None:
    with pytest.raises(IcdError) as e:
        ICD.command("PC.SETUP").encode(
            session_id=1, timestamp=0, duration_s=1000, max_packets=0, poll_frame_size=200
        )
    assert e.value.field == "duration_s"
    assert "1000 is outside the ICD's range 5..=900" in str(e.value)


@pytest.mark.parametrize(
    "args, field, words",
    [
        ({"mode": "sideways"}, "mode", 'one of "idle"'),
        ({"mode": 10}, "mode", "0..=9"),
        ({"mode": 1.5}, "mode", "not a whole number (u8)"),
        ({}, "mode", "missing"),
        ({"mode": 1, "speed": 2}, "speed", "no argument `speed`: mode"),
    ],
)
def test_bad_arguments_name_the_field(args: dict[str, object], field: str, words: str) -> None:
    with pytest.raises(IcdError) as e:
        ICD.command("FC.ATCMDSET").encode(**args)
    assert e.value.field == field and words in str(e.value)


def test_gaps_bits_and_text_fields() -> None:
    beacon = ICD.command("COMM.BEACONSET")
    assert beacon.encode(period_s="off")[1:] == b"\x00\x00"
    with pytest.raises(IcdError, match=re.escape("0..=3600 except 1..=9")):
        beacon.encode(period_s=5)
    per = ICD.command("FC.TMPERSET")
    mask_field = next(f for f in per.request.fields if f.name == "mask")
    assert mask_field.number(["TMGEN", "TMACD"]) == 0b101
    tle = ICD.command("FC.ATCTLESET")
    b = tle.encode(line1="1 25544U", line2="2 25544")
    assert len(b) == 1 + 138 and b[1:9] == b"1 25544U" and b[9] == 0
    with pytest.raises(IcdError, match="at most 69 characters"):
        tle.encode(line1="x" * 70, line2="")


def test_a_reply_decodes_with_names_units_and_paths() -> None:
    tmgen = ICD.command("FC.TMGEN")
    data = struct.pack("<IIIBBbB", 1777572012, 12, 12, 1, 0, 20, 0)
    r = tmgen.decode_reply(bytes([1, 1]) + data)
    assert r.ok and r["current_mode"] == 1 and r.name("current_mode") == "detumble"
    assert r["mcu_temp_c"] == 20
    assert "current_mode 1 (detumble)" in str(r)
    assert not tmgen.decode_reply(b"\x01\x00").ok
    with pytest.raises(ValueError, match="16"):
        tmgen.decode_reply(bytes([1, 1]) + data[:-1])


def test_nested_layouts_and_bit_names() -> None:
    tmpc = ICD.command("PC.TMPC")
    slot = struct.pack("<BBBBIIII", 1, 12, 2, 0, 30, 6000, 0, 0)
    data = slot + bytes(20 * 3) + struct.pack("<BII", 0b101, 0, 6000)
    r = tmpc.decode_reply(bytes([1, 1]) + data)
    assert r["slots[0].packets"] == 30
    slots = r["slots"]
    assert isinstance(slots, list) and isinstance(slots[0], dict) and slots[0]["state"] == 2
    assert r.value("slots[0].state", int) == 2
    assert r.name("slots[0].state") == "ACTIVE"
    assert r.name("sband_flags") == "on, transmitting"
    # One line per leaf, as the twin's `gs` and console `tm` print it: masks in hex.
    lines = [str(leaf) for leaf in r.leaves()]
    assert "slots[0].state 2 (ACTIVE)" in lines and "slots[0].downlinked_bytes 6000 B" in lines
    assert "sband_flags 0x5 (on, transmitting)" in lines


def test_the_sync_tail_and_the_length_limits() -> None:
    setup = ICD.command("PC.SETUP")
    with pytest.raises(IcdError, match=re.escape("129 bytes; the ICD allows 0..=128")):
        setup.encode(
            session_id=1,
            timestamp=0,
            duration_s=10,
            max_packets=0,
            poll_frame_size=1,
            sync_message=b"x" * 129,
        )
    status = ICD.command("PC.STATUS")
    head = struct.pack("<BBIHHB", 0, 2, 0, 10, 0, 200)
    r = status.decode_reply(bytes([2, 1]) + head + b"go")
    assert r.tail == b"go" and r.name("state") == "ACTIVE"


@pytest.mark.parametrize(
    "text, s", [("90", 90), ("90s", 90), ("100ms", 0.1), ("10m", 600), ("1h 30m", 5400)]
)
def test_durations_as_the_twin_writes_them(text: str, s: float) -> None:
    assert parse_duration_s(text) == pytest.approx(s)


def test_typed_reads_of_a_reply() -> None:
    tmgen = ICD.command("FC.TMGEN")
    data = struct.pack("<IIIBBbB", 1777572012, 12, 12, 1, 0, -20, 0)
    r = tmgen.decode_reply(bytes([tmgen.id, 1]) + data)
    temp: int = r.value("mcu_temp_c", int)
    assert temp - 1 == -21
    as_float = r.value("mcu_temp_c", float)
    assert isinstance(as_float, float) and as_float == -20.0
    with pytest.raises(TypeError, match="mcu_temp_c is int, not str"):
        r.value("mcu_temp_c", str)
    with pytest.raises(KeyError):
        r.value("mcu_temp", int)
    tmatp = ICD.command("FC.TMATP")
    data = struct.pack("<I4d3d", 5, 1.0, 0.0, 0.0, 0.0, 7e6, 0.0, 0.0)
    r = tmatp.decode_reply(bytes([tmatp.id, 1]) + data)
    q: list[float] = r.array("q_eci_from_body", float)
    assert q == [1.0, 0.0, 0.0, 0.0] and all(isinstance(x, float) for x in q)
    assert r.value("r_eci_m[0]", float) == 7e6 and r.value("rtc_timestamp", int) == 5
    with pytest.raises(TypeError, match=re.escape("q_eci_from_body[0] is float, not int")):
        r.array("q_eci_from_body", int)
    with pytest.raises(TypeError, match="rtc_timestamp is int, not an array"):
        r.array("rtc_timestamp", int)
    tle = ICD.command("FC.ATCTLEGET")
    r = tle.decode_reply(bytes([tle.id, 1]) + b"1 25544U".ljust(69, b"\0") + bytes(69))
    assert r.value("line1", str) == "1 25544U" and r.value("line2", str) == ""
    status = ICD.command("PC.STATUS")
    request = status.decode_request(bytes([status.id, 3]))
    assert request == {"session_id": 3}


def test_unknown_nodes_and_commands_list_what_there_is() -> None:
    with pytest.raises(IcdError, match="TMGEN"):
        ICD.command("FC.TMGENX")
    with pytest.raises(IcdError, match="COMM, FC, EPS"):
        ICD.command("OBC.PING")


def test_value_names_with_underscores_for_spaces() -> None:
    assert ICD.command("FC.ATCMDSET").encode(mode="velocity_pointing") == b"\x06\x02"
    assert ICD.command("FC.ATCMDSET").encode(mode="Velocity Pointing") == b"\x06\x02"


def test_names_with_hyphens_and_the_whole_u64_range() -> None:
    status = ICD.command("PC.STATUS")
    last = next(f for f in status.reply.fields if f.name == "last_result")
    assert last.number("s_band_failure") == 3 and last.number("S-BAND FAILURE") == 3
    fread = ICD.command("PC.FREAD")
    b = fread.encode(payload_addr=12, offset=2**64 - 1, length=200)
    assert b[2:10] == b"\xff" * 8
