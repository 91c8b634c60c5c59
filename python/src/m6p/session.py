"""The payload data sessions of the payload controller (PC, CSP 6; ICD 3.1.8), from both
ends: :class:`Payload` is what a payload does in a polling session (answer SYNC and
POLL), :class:`Session` is what the ground does (SETUP, STATUS, ABORT, wait for the end).

::

    payload = Payload(CspNode(KissTcp(twin.payload_addr), 12), source=my_frames)
    session = Session(ground, 1)
    session.setup(duration_s="10s", max_packets=25, poll_frame_size=200, sync_message="go")
    session.wait_done()
"""

from __future__ import annotations

import threading
import time
from typing import Callable

from .csp import Packet
from .icd import Reply
from .node import CspNode

__all__ = ["FrameSource", "Payload", "Session", "counter_frames"]

#: Where a payload's POLL replies come from: the frame size asked for in, the data (at
#: most that many bytes) out.
FrameSource = Callable[[int], bytes]

#: The PC's states and results (STATUS, TMPC), by the ICD's names.
NOT_ACTIVE, PENDING, ACTIVE = 0, 1, 2
DONE, ABORTED, NO_ACK, SBAND_FAILURE = 0, 1, 2, 3


def counter_frames() -> FrameSource:
    """A deterministic stream (``examples/outside_payload.py``'s ``frame_data``): frame
    ``seq`` is ``seq`` as u16 little-endian then a byte counter from ``seq``, and its
    length cycles through all, two thirds and one third of the size asked for."""
    seq = 0

    def next_frame(frame_size: int) -> bytes:
        nonlocal seq
        length = max(1, frame_size - (seq % 3) * (frame_size // 3))
        frame = (seq & 0xFFFF).to_bytes(2, "little")[:length] + bytes(
            (seq + i) & 0xFF for i in range(max(0, length - 2))
        )
        seq += 1
        return frame[:length]

    return next_frame


class Payload:
    """A payload serving the PC's polling sessions on ``port`` (10) of ``node``:

    - SYNC ``01 | message`` is answered ``01 01 | message`` (``on_sync`` may refuse it by
      returning False);
    - POLL ``02 | frameSize`` is answered ``02 01 | data`` with ``source(frameSize)``
      (cut to frameSize bytes);
    - anything else gets the failure reply ``command 00``.

    ``sent`` holds every data byte sent in POLL replies, in order: compare it with what
    reached the ground. ``syncs`` holds the sync messages, ``polls`` counts POLLs.
    """

    def __init__(
        self,
        node: CspNode,
        port: int = 10,
        source: FrameSource | None = None,
        on_sync: Callable[[bytes], bool] | None = None,
    ) -> None:
        self.node = node
        self.port = port
        self.source = source if source is not None else counter_frames()
        self.on_sync = on_sync
        self.sent = bytearray()
        self.syncs: list[bytes] = []
        self.polls = 0
        self.refused = 0
        self.last_poll: float | None = None
        self._changed = threading.Condition()
        icd = node.icd
        self._sync = icd.command("payload.SYNC")
        self._poll = icd.command("payload.POLL")
        node.serve(port, self._handle)

    def _handle(self, p: Packet) -> bytes:
        data = p.data
        cmd = data[0] if data else 0
        try:
            if cmd == self._sync.id:
                message = self._sync.decode_request(data)["message"]
                if not isinstance(message, bytes):
                    raise ValueError("SYNC: the ICD's message is not a tail")
                if self.on_sync is not None and not self.on_sync(message):
                    return self._sync.reply_bytes(ok=False)
                with self._changed:
                    self.syncs.append(message)
                    self._changed.notify_all()
                return self._sync.reply_bytes(message=message)
            if cmd == self._poll.id:
                size = self._poll.decode_request(data)["frame_size"]
                if not isinstance(size, int):
                    raise ValueError("POLL: the ICD's frame_size is not an integer")
                if size == 0:
                    raise ValueError("frameSize 0")
                out = bytes(self.source(size))[:size]
                with self._changed:
                    self.sent += out
                    self.polls += 1
                    self.last_poll = time.monotonic()
                    self._changed.notify_all()
                return self._poll.reply_bytes(data=out)
        except ValueError:
            pass
        self.refused += 1
        return bytes([cmd, 0])

    def wait(self, predicate: Callable[[Payload], bool], timeout_s: float = 30.0) -> None:
        """Wait until ``predicate(self)`` holds; ``TimeoutError`` after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while not predicate(self):
                left = deadline - time.monotonic()
                if left <= 0 or self.node.closed.is_set():
                    raise TimeoutError(
                        f"payload {self.node.addr}: {len(self.syncs)} SYNC, {self.polls} POLL "
                        f"after {timeout_s} s"
                    )
                self._changed.wait(min(left, 0.1))

    def wait_polls(self, n: int, timeout_s: float = 30.0) -> None:
        """Wait for ``n`` POLLs in all."""
        self.wait(lambda p: p.polls >= n, timeout_s)


class Session:
    """Session ``session_id`` of the PC, driven from a ground node (ICD 3.1.8.1)."""

    def __init__(self, ground: CspNode, session_id: int, pc: int | None = None) -> None:
        self.ground = ground
        self.session_id = session_id
        self.pc = pc

    def setup(
        self,
        duration_s: int | str,
        poll_frame_size: int = 200,
        max_packets: int = 0,
        timestamp: int | str = 0,
        sync_message: bytes | str = b"",
        *,
        port: int | None = None,
        timeout_s: float | None = None,
        **kw: object,
    ) -> Reply:
        """SETUP (``timestamp`` 0: start now; ``max_packets`` 0: no limit). Raises
        ``RuntimeError`` when the PC refuses it (the twin logs why). ``port`` and
        ``timeout_s`` as :meth:`m6p.node.CspNode.command` takes them; ``kw``: more of the
        command's arguments."""
        r = self.ground.command(
            "PC.SETUP",
            to=self.pc,
            port=port,
            timeout_s=timeout_s,
            raw=None,
            session_id=self.session_id,
            timestamp=timestamp,
            duration_s=duration_s,
            max_packets=max_packets,
            poll_frame_size=poll_frame_size,
            sync_message=sync_message,
            **kw,
        )
        if not r.ok:
            raise RuntimeError(f"the PC refused SETUP of session {self.session_id}")
        return r

    def status(self) -> Reply:
        """STATUS: ``state`` (0 NOT ACTIVE, 1 PENDING, 2 ACTIVE), ``last_result``
        (0 DONE, 1 ABORTED, 2 NO ACK, 3 S-BAND FAILURE) and the SETUP in effect."""
        return self.ground.command("PC.STATUS", to=self.pc, session_id=self.session_id)

    def abort(self) -> Reply:
        return self.ground.command("PC.ABORT", to=self.pc, session_id=self.session_id)

    def wait_done(self, timeout_s: float = 60.0, every_s: float = 0.5) -> Reply:
        """Poll STATUS until the session is over (NOT ACTIVE after having been PENDING or
        ACTIVE, or NOT ACTIVE at the first look); returns that STATUS."""
        deadline = time.monotonic() + timeout_s
        while True:
            s = self.status()
            if s.ok and s["state"] == NOT_ACTIVE:
                return s
            if time.monotonic() >= deadline:
                raise TimeoutError(
                    f"session {self.session_id} still {s.name('state') if s.ok else 'unknown'} "
                    f"after {timeout_s} s"
                )
            time.sleep(every_s)
