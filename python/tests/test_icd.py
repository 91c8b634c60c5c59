"""The ICD as data: typed encoding checked against the ICD's ranges, decoding."""
import struct

import pytest

from m6p.icd import Icd, IcdError, parse_duration_s

ICD = Icd.load()


def test_every_commands_example_decodes_and_encodes_back_to_the_same_bytes():
    checked = 0
    for c in ICD.commands():
        if c.example is None or not c.request.described:
            continue
        request = bytes([c.id]) + c.example
        args = c.decode_request(request)
        if c.request.tail is not None:
            args[c.request.tail.name] = bytes(args[c.request.tail.name])
        assert c.encode(**args) == request, c.full_name
        checked += 1
    assert checked >= 19


def test_a_setup_encodes_with_durations_and_names_as_the_icd_lays_it_out():
    setup = ICD.command("pc.setup")
    b = setup.encode(session_id=1, timestamp="now", duration_s="3m", max_packets="no limit",
                     poll_frame_size=200, sync_message="go")
    assert b == bytes([1, 1]) + struct.pack("<IHHB", 0, 180, 0, 200) + b"go"


def test_a_1000_s_setup_is_refused_naming_the_field_and_the_icd_range():
    with pytest.raises(IcdError) as e:
        ICD.command("PC.SETUP").encode(session_id=1, timestamp=0, duration_s=1000,
                                       max_packets=0, poll_frame_size=200)
    assert e.value.field == "duration_s"
    assert "1000 is outside the ICD's range 5..=900" in str(e.value)


@pytest.mark.parametrize(
    "args, field, words",
    [
        (dict(mode="sideways"), "mode", 'one of "idle"'),
        (dict(mode=10), "mode", "0..=9"),
        (dict(mode=1.5), "mode", "not a whole number (u8)"),
        (dict(), "mode", "missing"),
        (dict(mode=1, speed=2), "speed", "no argument `speed`: mode"),
    ],
)
def test_bad_arguments_name_the_field(args, field, words):
    with pytest.raises(IcdError) as e:
        ICD.command("FC.ATCMDSET").encode(**args)
    assert e.value.field == field and words in str(e.value)


def test_gaps_bits_and_text_fields():
    beacon = ICD.command("COMM.BEACONSET")
    assert beacon.encode(period_s="off")[1:] == b"\x00\x00"
    with pytest.raises(IcdError, match="0..=3600 except 1..=9"):
        beacon.encode(period_s=5)
    per = ICD.command("FC.TMPERSET")
    mask_field = next(f for f in per.request.fields if f.name == "mask")
    assert mask_field.number(["TMGEN", "TMACD"]) == 0b101
    tle = ICD.command("FC.ATCTLESET")
    b = tle.encode(line1="1 25544U", line2="2 25544")
    assert len(b) == 1 + 138 and b[1:9] == b"1 25544U" and b[9] == 0
    with pytest.raises(IcdError, match="at most 69 characters"):
        tle.encode(line1="x" * 70, line2="")


def test_a_reply_decodes_with_names_units_and_paths():
    tmgen = ICD.command("FC.TMGEN")
    data = struct.pack("<IIIBBbB", 1777572012, 12, 12, 1, 0, 20, 0)
    r = tmgen.decode_reply(bytes([1, 1]) + data)
    assert r.ok and r["current_mode"] == 1 and r.name("current_mode") == "detumble"
    assert r["mcu_temp_c"] == 20
    assert "current_mode 1 (detumble)" in str(r)
    assert not tmgen.decode_reply(b"\x01\x00").ok
    with pytest.raises(ValueError, match="16"):
        tmgen.decode_reply(bytes([1, 1]) + data[:-1])


def test_nested_layouts_and_bit_names():
    tmpc = ICD.command("PC.TMPC")
    slot = struct.pack("<BBBBIIII", 1, 12, 2, 0, 30, 6000, 0, 0)
    data = slot + bytes(20 * 3) + struct.pack("<BII", 0b101, 0, 6000)
    r = tmpc.decode_reply(bytes([1, 1]) + data)
    assert r["slots[0].packets"] == 30 and r["slots"][0]["state"] == 2
    assert r.name("slots[0].state") == "ACTIVE"
    assert r.name("sband_flags") == "on, transmitting"


def test_the_sync_tail_and_the_length_limits():
    setup = ICD.command("PC.SETUP")
    with pytest.raises(IcdError, match="129 bytes; the ICD allows 0..=128"):
        setup.encode(session_id=1, timestamp=0, duration_s=10, max_packets=0,
                     poll_frame_size=1, sync_message=b"x" * 129)
    status = ICD.command("PC.STATUS")
    head = struct.pack("<BBIHHB", 0, 2, 0, 10, 0, 200)
    r = status.decode_reply(bytes([2, 1]) + head + b"go")
    assert r.tail == b"go" and r.name("state") == "ACTIVE"


@pytest.mark.parametrize(
    "text, s", [("90", 90), ("90s", 90), ("100ms", 0.1), ("10m", 600), ("1h 30m", 5400)]
)
def test_durations_as_the_twin_writes_them(text, s):
    assert parse_duration_s(text) == pytest.approx(s)


def test_unknown_nodes_and_commands_list_what_there_is():
    with pytest.raises(IcdError, match="TMGEN"):
        ICD.command("FC.TMGENX")
    with pytest.raises(IcdError, match="COMM, FC, EPS"):
        ICD.command("OBC.PING")


def test_value_names_with_underscores_for_spaces():
    assert ICD.command("FC.ATCMDSET").encode(mode="velocity_pointing") == b"\x06\x02"
    assert ICD.command("FC.ATCMDSET").encode(mode="Velocity Pointing") == b"\x06\x02"


def test_names_with_hyphens_and_the_whole_u64_range():
    status = ICD.command("PC.STATUS")
    last = next(f for f in status.reply.fields if f.name == "last_result")
    assert last.number("s_band_failure") == 3 and last.number("S-BAND FAILURE") == 3
    fread = ICD.command("PC.FREAD")
    b = fread.encode(payload_addr=12, offset=2**64 - 1, length=200)
    assert b[2:10] == b"\xff" * 8
