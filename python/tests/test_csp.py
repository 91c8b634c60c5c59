"""CSP 1.4 on the wire against libcsp 1.4's own vectors (tests/data)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TypedDict, cast

import pytest

from m6p.csp import (
    FLAG_CRC32,
    KISS_MTU_LIBCSP14,
    Header,
    KissDecoder,
    Packet,
    crc32c,
    kiss_encode,
    zmq_decode,
    zmq_encode,
)

DATA = Path(__file__).parent / "data"


class Fields(TypedDict):
    """A header's fields, as :class:`m6p.csp.Header` takes them."""

    prio: int
    src: int
    dst: int
    dport: int
    sport: int
    flags: int


class Crc32Case(TypedDict):
    name: str
    input: str
    crc: str
    appended: str


class HeaderCase(TypedDict):
    fields: Fields
    word: str
    wire: str


class KissEncodeCase(TypedDict):
    name: str
    fields: Fields
    data: str
    inner_crc: bool
    wire: str


class KissPacket(TypedDict):
    fields: Fields
    data: str


class KissDecodeCase(TypedDict):
    name: str
    input: str
    packets: list[KissPacket]
    rx_error: int
    discarded_bytes: int


def cases(name: str) -> object:
    """The ``cases`` of ``tests/data/NAME.json`` (the classes above give their shapes)."""
    return json.loads((DATA / f"{name}.json").read_text())["cases"]


CRC32 = cast("list[Crc32Case]", cases("crc32"))
HEADER = cast("list[HeaderCase]", cases("header"))
KISS_ENCODE = cast("list[KissEncodeCase]", cases("kiss_encode"))
KISS_DECODE = cast("list[KissDecodeCase]", cases("kiss_decode"))


@pytest.mark.parametrize("case", CRC32, ids=lambda c: c["name"])
def test_crc32c_is_libcsps(case: Crc32Case) -> None:
    crc = crc32c(bytes.fromhex(case["input"]))
    assert crc == int(case["crc"], 16)
    assert crc.to_bytes(4, "big").hex() == case["appended"]


@pytest.mark.parametrize("case", HEADER, ids=lambda c: c["wire"])
def test_the_header_is_libcsps(case: HeaderCase) -> None:
    h = Header(**case["fields"])
    assert h.word == int(case["word"], 16)
    assert h.pack().hex() == case["wire"]
    assert Header.unpack(bytes.fromhex(case["wire"])) == h


@pytest.mark.parametrize("case", KISS_ENCODE, ids=lambda c: c["name"])
def test_kiss_frames_are_libcsps(case: KissEncodeCase) -> None:
    data = bytes.fromhex(case["data"])
    p = Packet(Header(**case["fields"]), data)
    if case["inner_crc"]:
        p = p.with_csp_crc()
    assert kiss_encode(p).hex() == case["wire"]
    assert KissDecoder().feed(bytes.fromhex(case["wire"])) == [p]


# One leniency on purpose (m6p.csp.KissDecoder): a FEND shared by two frames closes the
# first and opens the second, which libcsp 1.4 loses.
SHARED_FEND = "two frames sharing one FEND (C0 00 f1 C0 00 f2 C0): second frame is lost"


@pytest.mark.parametrize("case", KISS_DECODE, ids=lambda c: c["name"])
def test_the_kiss_receiver_does_what_libcsps_does(case: KissDecodeCase) -> None:
    d = KissDecoder(mtu=KISS_MTU_LIBCSP14)
    got = d.feed(bytes.fromhex(case["input"]))
    want = [Packet(Header(**p["fields"]), bytes.fromhex(p["data"])) for p in case["packets"]]
    if case["name"] == SHARED_FEND:
        assert got == want * 2 and d.rx_errors == 0
        return
    assert got == want
    assert d.rx_errors == case["rx_error"]
    assert d.discarded_bytes == case["discarded_bytes"]


def test_the_receiver_takes_frames_split_anywhere_and_is_bounded() -> None:
    p = Packet(Header(2, 12, 6, 10, 33), bytes(range(256)) * 2)
    wire = kiss_encode(p) * 3
    d = KissDecoder()
    got = []
    for i in range(0, len(wire), 7):
        got += d.feed(wire[i : i + 7])
    assert got == [p] * 3
    small = KissDecoder(mtu=100)
    assert small.feed(wire) == [] and small.rx_errors == 3


def test_a_csp_crc_is_checked_and_stripped() -> None:
    p = Packet(Header(2, 6, 12, 10, 40, FLAG_CRC32), b"\x02\xc8")
    sent = p.with_csp_crc()
    assert sent.strip_csp_crc() == p
    damaged = Packet(sent.header, sent.data[:-1] + bytes([sent.data[-1] ^ 1]))
    assert damaged.strip_csp_crc() is None


def test_zmq_hub_messages_are_via_then_the_little_endian_header() -> None:
    p = Packet(Header(2, 6, 12, 10, 40), b"\x01go")
    msg = zmq_encode(p)
    assert msg[0] == 12 and msg[1:5] == p.header.word.to_bytes(4, "little")
    assert zmq_decode(msg) == p
    assert zmq_decode(msg[:4]) is None
    assert zmq_decode(msg[:5] + bytes(257)) is None


def test_header_fields_out_of_range_are_refused() -> None:
    with pytest.raises(ValueError, match="dport 64"):
        Header(2, 1, 2, 64, 0)
