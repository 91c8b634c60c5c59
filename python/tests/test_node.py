"""CspNode over an in-memory link: requests, servers, pings, CRC, timeouts."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterator

import pytest

from m6p.csp import FLAG_CRC32, Header, Packet
from m6p.links import LinkClosed
from m6p.node import CspNode, CspTimeout

Pair = tuple[CspNode, CspNode]


class End:
    """One end of an in-memory link (an m6p.links.Link)."""

    def __init__(self, inbox: queue.Queue[Packet], outbox: queue.Queue[Packet]) -> None:
        self.inbox, self.outbox = inbox, outbox

    def send(self, p: Packet) -> None:
        self.outbox.put(p)

    def recv(self, timeout_s: float) -> Packet | None:
        try:
            return self.inbox.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def close(self) -> None:
        pass


@pytest.fixture
def pair() -> Iterator[Pair]:
    a_in: queue.Queue[Packet] = queue.Queue()
    b_in: queue.Queue[Packet] = queue.Queue()
    a = CspNode(End(a_in, b_in), 17, timeout_s=1.0)
    b = CspNode(End(b_in, a_in), 12, timeout_s=1.0)
    yield a, b
    a.close()
    b.close()


def test_a_request_gets_the_servers_reply_and_pings_are_echoed(pair: Pair) -> None:
    ground, payload = pair
    seen: list[Header] = []

    def handler(p: Packet) -> bytes:
        seen.append(p.header)
        return b"\x01\x01" + p.data[1:]

    payload.serve(10, handler)
    assert ground.request(12, 10, b"\x01go") == b"\x01\x01go"
    h = seen[0]
    assert (h.src, h.dst, h.dport) == (17, 12, 10) and 32 <= h.sport <= 63
    assert ground.ping(12, size=100) < 1.0


def test_a_crc_request_gets_a_crc_reply_and_nobody_answers_an_unbound_port(pair: Pair) -> None:
    ground, payload = pair
    payload.serve(10, lambda p: p.data)
    assert ground.request(12, 10, b"abc", flags=FLAG_CRC32) == b"abc"
    with pytest.raises(CspTimeout, match="no reply from 12:11"):
        ground.request(12, 11, b"x", timeout_s=0.2)
    assert payload.unhandled == 1


def test_a_handlers_exception_is_counted_and_the_node_goes_on(pair: Pair) -> None:
    ground, payload = pair
    calls: list[Packet] = []

    def handler(p: Packet) -> bytes:
        calls.append(p)
        if len(calls) == 1:
            raise RuntimeError("a bug in the payload")
        return b"ok"

    payload.serve(10, handler)
    with pytest.raises(CspTimeout):
        ground.request(12, 10, b"1", timeout_s=0.2)
    assert ground.request(12, 10, b"2") == b"ok"
    assert payload.handler_errors == 1


def test_icd_commands_by_name_between_two_python_nodes(pair: Pair) -> None:
    ground, fc = pair
    tmgen = fc.icd.command("FC.TMGEN")
    fc.serve(
        10,
        lambda p: tmgen.reply_bytes(
            rtc_timestamp=1,
            uptime_s=2,
            global_on_time_s=3,
            current_mode="nadir",
            current_state=0,
            mcu_temp_c=-5,
            reset_cause=0,
        ),
    )
    r = ground.command("FC.TMGEN", to=12)
    assert r.ok and r.name("current_mode") == "nadir" and r["mcu_temp_c"] == -5


def test_a_reply_must_come_from_where_the_request_went_and_close_releases_waiters(
    pair: Pair,
) -> None:
    ground, payload = pair

    # A packet to the request's port from another address is not its reply.
    def impostor(p: Packet) -> None:
        payload.link.send(Packet(Header(2, 13, 17, p.header.sport, 10), b"not yours"))

    payload.serve(10, impostor)
    with pytest.raises(CspTimeout):
        ground.request(12, 10, b"x", timeout_s=0.3)
    # A request waiting when the node closes ends at once.
    payload.serve(10, lambda p: None)
    result: list[LinkClosed] = []

    def ask() -> None:
        try:
            ground.request(12, 10, b"y", timeout_s=10.0)
        except LinkClosed as e:
            result.append(e)

    t = threading.Thread(target=ask)
    t.start()
    time.sleep(0.2)
    ground.close()
    t.join(timeout=2.0)
    assert not t.is_alive() and len(result) == 1
