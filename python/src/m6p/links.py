"""Links from a Python program to the twin (or to any libcsp 1.4 network): KISS over TCP
(the twin's ``--kiss-listen``, ICD 2.3) and libcsp 1.4's ZMQ hub (the twin's
``--zmq-hub``; needs ``pyzmq``: ``pip install ./python[zmq]``).

A link moves whole CSP packets: :meth:`send` and :meth:`recv`. It knows nothing of
addresses or ports (see :class:`m6p.node.CspNode`).
"""

from __future__ import annotations

import contextlib
import select
import socket
import time
from typing import Protocol

from .csp import KissDecoder, Packet, kiss_encode, zmq_decode, zmq_encode

__all__ = ["KissTcp", "Link", "LinkClosed", "ZmqHub", "parse_hostport"]


class LinkClosed(ConnectionError):
    """The other end closed the link (the twin's run ended)."""


class Link(Protocol):
    """What :class:`m6p.node.CspNode` needs of a link."""

    def send(self, packet: Packet) -> None: ...

    def recv(self, timeout_s: float) -> Packet | None:
        """The next packet, or None after ``timeout_s``; :class:`LinkClosed` when the
        link is gone."""
        ...

    def close(self) -> None: ...


def parse_hostport(addr: str | tuple[str, int]) -> tuple[str, int]:
    """``"127.0.0.1:52001"`` or ``("127.0.0.1", 52001)``."""
    if isinstance(addr, tuple):
        return addr
    host, sep, port = addr.rpartition(":")
    if not sep or not port.isdigit():
        raise ValueError(f"`{addr}` is not HOST:PORT")
    return host, int(port)


class KissTcp:
    """KISS over TCP, as libcsp 1.4's KISS interface frames it (CRC-32C on every frame).

    Connects to ``addr`` (``"127.0.0.1:52001"``), trying again every 100 ms for up to
    ``connect_timeout_s`` (so the program may start before the twin). ``mtu``: see
    :class:`m6p.csp.KissDecoder`. Damaged frames are counted in ``decoder.rx_errors``.
    """

    def __init__(
        self,
        addr: str | tuple[str, int],
        connect_timeout_s: float = 10.0,
        mtu: int | None = None,
    ) -> None:
        self.addr = parse_hostport(addr)
        deadline = time.monotonic() + connect_timeout_s
        while True:
            try:
                self.sock = socket.create_connection(self.addr, timeout=1.0)
                break
            except OSError:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(0.1)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        # Blocking: `recv` waits with `select`, so a send never inherits a short timeout.
        self.sock.settimeout(None)
        self.decoder = KissDecoder(mtu)
        self._ready: list[Packet] = []
        self._closed = False

    def send(self, packet: Packet) -> None:
        self.sock.sendall(kiss_encode(packet))

    def recv(self, timeout_s: float) -> Packet | None:
        deadline = time.monotonic() + timeout_s
        while not self._ready:
            if self._closed:
                raise LinkClosed(f"{self.addr[0]}:{self.addr[1]} closed the connection")
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            try:
                ready, _, _ = select.select([self.sock], [], [], left)
                if not ready:
                    return None
                chunk = self.sock.recv(4096)
            except (OSError, ValueError) as e:
                self._closed = True
                raise LinkClosed(str(e)) from e
            if not chunk:
                self._closed = True
                continue
            self._ready.extend(self.decoder.feed(chunk))
        return self._ready.pop(0)

    def close(self) -> None:
        self._closed = True
        with contextlib.suppress(OSError):
            self.sock.close()


class ZmqHub:
    """libcsp 1.4's ZMQ hub interface (``csp_zmqhub_init(addr, host)``): a PUB socket
    connected to ``tcp://host:publish_port`` (6000) and a SUB socket, subscribed to this
    node's address byte, connected to ``tcp://host:subscribe_port`` (7000). Messages are
    ``via | header (little-endian) | data`` (:func:`m6p.csp.zmq_encode`).

    ZMQ subscriptions take a moment to reach the publisher: packets sent to this node in
    the first few milliseconds after it connects may be lost, as with libcsp; the
    constructor waits ``settle_s`` for it.
    """

    def __init__(
        self,
        host: str,
        addr: int,
        publish_port: int = 6000,
        subscribe_port: int = 7000,
        promiscuous: bool = False,
        settle_s: float = 0.1,
    ) -> None:
        try:
            import zmq
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError("the ZMQ hub link needs pyzmq: pip install './python[zmq]'") from e
        self._zmq = zmq
        self.ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
        self.pub = self.ctx.socket(zmq.PUB)
        self.pub.setsockopt(zmq.LINGER, 0)
        self.pub.connect(f"tcp://{host}:{publish_port}")
        self.sub = self.ctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.LINGER, 0)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"" if promiscuous else bytes([addr]))
        self.sub.connect(f"tcp://{host}:{subscribe_port}")
        self.dropped = 0
        # Give the subscription time to reach the hub before anyone sends to this node.
        time.sleep(settle_s)

    def send(self, packet: Packet) -> None:
        self.pub.send(zmq_encode(packet))

    def recv(self, timeout_s: float) -> Packet | None:
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not self.sub.poll(int(left * 1000) + 1):
                return None
            p = zmq_decode(self.sub.recv())
            if p is not None:
                return p
            self.dropped += 1

    def close(self) -> None:
        self.pub.close(0)
        self.sub.close(0)
