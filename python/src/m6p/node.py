"""A CSP node in Python: requests with replies, ICD commands by name, and servers on
ports, over any :class:`m6p.links.Link`.

One background thread reads the link: a reply to an outstanding request (a packet to one
of this node's ephemeral ports) goes to the request that waits for it; a packet to a port
with a handler (:meth:`CspNode.serve`) runs the handler in that thread and its answer goes
back as a reply; pings are echoed (port 1) as any libcsp node does. Anything else is
counted in ``unhandled`` and dropped, as libcsp drops a packet for a port nobody bound.
"""

from __future__ import annotations

import queue
import threading
import time
from typing import TYPE_CHECKING, Callable, Optional

from .csp import FLAG_CRC32, PORT_PING, PRIO_NORM, Header, Packet
from .icd import Command, Icd, Reply
from .links import Link, LinkClosed

if TYPE_CHECKING:
    # Only for the checker (it comes with it): Python 3.11 has typing.Self, but this
    # package runs from 3.9 on, without dependencies.
    from typing_extensions import Self

__all__ = ["CspNode", "CspTimeout", "Handler"]

#: A server's handler: the request packet (its data without a CSP CRC) in, the reply's
#: data (or None for no reply) out.
Handler = Callable[[Packet], Optional[bytes]]

# libcsp 1.4's outgoing ports: above the bindable 0..=31 (CSP_MAX_BIND_PORT).
_EPHEMERAL = range(32, 64)


class CspTimeout(TimeoutError):
    """No reply in time."""


class CspNode:
    """A CSP node with address ``addr`` on ``link``.

    ``icd``: the ICD used by :meth:`command` (default: the package's copy).
    ``timeout_s``: how long a request waits for its reply unless told otherwise.
    """

    def __init__(
        self,
        link: Link,
        addr: int,
        icd: Icd | None = None,
        timeout_s: float = 5.0,
        prio: int = PRIO_NORM,
    ) -> None:
        if not 0 <= addr <= 30:
            raise ValueError(f"CSP address {addr} is outside 0..=30")
        self.link = link
        self.addr = addr
        self.icd = icd if icd is not None else Icd.load()
        self.timeout_s = timeout_s
        self.prio = prio
        self.handlers: dict[int, Handler] = {}
        self.unhandled = 0
        self.handler_errors = 0
        self.closed = threading.Event()
        self._lock = threading.Lock()
        # Outstanding requests by their source port: (destination, its port, the queue the
        # reply goes to; None in it means the link closed).
        self._waiting: dict[int, tuple[int, int, queue.Queue[Packet | None]]] = {}
        self._send_lock = threading.Lock()
        self._next_port = 0
        self._thread = threading.Thread(target=self._read, name=f"csp-{addr}", daemon=True)
        self._thread.start()

    # -- sending -------------------------------------------------------------------------

    def send(
        self,
        dst: int,
        dport: int,
        data: bytes,
        sport: int = 0,
        flags: int = 0,
        prio: int | None = None,
    ) -> None:
        """One packet, connection-less (``csp_sendto``)."""
        p = Packet(
            Header(self.prio if prio is None else prio, self.addr, dst, dport, sport, flags),
            bytes(data),
        )
        if flags & FLAG_CRC32:
            p = p.with_csp_crc()
        self._send(p)

    def _send(self, p: Packet) -> None:
        """One sender at a time (the caller's thread and the reader's: a socket, and a ZMQ
        socket above all, is not to be written from two threads at once)."""
        if self.closed.is_set():
            raise LinkClosed("the link is closed")
        with self._send_lock:
            self.link.send(p)

    def request(
        self,
        dst: int,
        dport: int,
        data: bytes = b"",
        timeout_s: float | None = None,
        flags: int = 0,
    ) -> bytes:
        """Send ``data`` to ``dst:dport`` from a free ephemeral port and return the data
        of the first packet back to that port (``csp_transaction``);
        :class:`CspTimeout` when none comes in time."""
        q: queue.Queue[Packet | None] = queue.Queue()
        sport = self._take_port(dst, dport, q)
        wait_s = self.timeout_s if timeout_s is None else timeout_s
        try:
            self.send(dst, dport, data, sport=sport, flags=flags)
            try:
                p = q.get(timeout=wait_s)
            except queue.Empty:
                raise CspTimeout(f"no reply from {dst}:{dport} in {wait_s} s") from None
            if p is None:
                raise LinkClosed("the link closed before the reply came")
            return p.data
        finally:
            with self._lock:
                self._waiting.pop(sport, None)

    def ping(self, dst: int, size: int = 8, timeout_s: float | None = None) -> float:
        """Round trip of a ping to ``dst`` (port 1) in seconds; the echo must be the
        same bytes."""
        data = bytes(i & 0xFF for i in range(size))
        t0 = time.monotonic()
        back = self.request(dst, PORT_PING, data, timeout_s=timeout_s)
        if back != data:
            raise ValueError(f"ping {dst}: the echo differs ({len(back)} bytes back)")
        return time.monotonic() - t0

    def command(
        self,
        name: str,
        *,
        to: int | None = None,
        port: int | None = None,
        timeout_s: float | None = None,
        raw: bytes | None = None,
        **args: object,
    ) -> Reply:
        """Send the ICD command ``name`` (``"PC.SETUP"``) with typed arguments and return
        its decoded reply: ``ground.command("FC.ATCMDSET", mode="nadir").ok``.

        ``to``: the address (default: the node's first); ``port``: the port (default:
        the ICD's); ``raw``: request data as bytes, for a command whose layout varies.
        Arguments are checked before anything is sent (:class:`m6p.icd.IcdError`)."""
        c: Command = self.icd.command(name)
        request = c.encode_raw(raw) if raw is not None else c.encode(**args)
        dst = c.node.addrs[0] if to is None else to
        back = self.request(dst, c.port if port is None else port, request, timeout_s=timeout_s)
        return c.decode_reply(back)

    # -- serving -------------------------------------------------------------------------

    def serve(self, port: int, handler: Handler) -> None:
        """Answer requests to ``port`` with ``handler`` (run in the reader thread). The
        reply goes to the request's source address and port, from ``port``, with its
        priority and flags (a CSP CRC is added when the request had one)."""
        self.handlers[port] = handler

    # -- the reader ----------------------------------------------------------------------

    def _take_port(self, dst: int, dport: int, q: queue.Queue[Packet | None]) -> int:
        with self._lock:
            for _ in _EPHEMERAL:
                port = _EPHEMERAL[self._next_port % len(_EPHEMERAL)]
                self._next_port += 1
                if port not in self._waiting:
                    self._waiting[port] = (dst, dport, q)
                    return port
        raise RuntimeError("all 32 outgoing ports are waiting for replies")

    def _release_waiters(self) -> None:
        with self._lock:
            for _, _, q in self._waiting.values():
                q.put(None)

    def _read(self) -> None:
        while not self.closed.is_set():
            try:
                p = self.link.recv(0.1)
            except (LinkClosed, OSError):
                self.closed.set()
                self._release_waiters()
                return
            if p is not None:
                self._dispatch(p)

    def _dispatch(self, p: Packet) -> None:
        h = p.header
        if h.dst != self.addr:
            self.unhandled += 1
            return
        checked = p.strip_csp_crc()
        if checked is None:
            self.unhandled += 1
            return
        p = checked
        with self._lock:
            waiting = self._waiting.get(h.dport)
        # A reply: to the request's port, from the address and port it went to (a late
        # reply to an earlier request from the same port is not this one's).
        if waiting is not None and (h.src, h.sport) == waiting[:2] and h.dport not in self.handlers:
            waiting[2].put(p)
            return
        handler = self.handlers.get(h.dport)
        if handler is None and h.dport == PORT_PING:

            def handler(q: Packet) -> bytes:
                return q.data

        if handler is None:
            self.unhandled += 1
            return
        try:
            reply = handler(p)
        except Exception:  # noqa: BLE001 - a handler's bug must not stop the node
            self.handler_errors += 1
            import traceback

            traceback.print_exc()
            return
        if reply is not None:
            out = Packet(h.reply(), bytes(reply))
            if h.flags & FLAG_CRC32:
                out = out.with_csp_crc()
            try:
                self._send(out)
            except OSError:
                self.closed.set()
                self._release_waiters()

    def close(self) -> None:
        """Stop the reader and close the link; requests still waiting get
        :class:`m6p.links.LinkClosed`."""
        self.closed.set()
        self._release_waiters()
        self._thread.join(timeout=1.0)
        self.link.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
