"""CSP 1.4 on the wire, as libcsp 1.4 writes it: the header, CRC-32C, KISS and the ZMQ
hub's message format (docs/protocol.md; the golden vectors in python/tests/data are
libcsp 1.4's own output).

Pure functions and one small decoder class; no sockets here (see :mod:`m6p.links`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

__all__ = [
    "FLAG_CRC32",
    "FLAG_FRAG",
    "FLAG_HMAC",
    "FLAG_RDP",
    "FLAG_XTEA",
    "PORT_PING",
    "PRIO_CRITICAL",
    "PRIO_HIGH",
    "PRIO_LOW",
    "PRIO_NORM",
    "Header",
    "KissDecoder",
    "Packet",
    "crc32c",
    "kiss_encode",
    "zmq_decode",
    "zmq_encode",
]

# Header flags (libcsp 1.4 csp_types.h).
FLAG_CRC32 = 0x01
FLAG_RDP = 0x02
FLAG_XTEA = 0x04
FLAG_HMAC = 0x08
FLAG_FRAG = 0x10

PRIO_CRITICAL, PRIO_HIGH, PRIO_NORM, PRIO_LOW = 0, 1, 2, 3

#: The CSP service port every libcsp node answers pings on.
PORT_PING = 1

# ---------------------------------------------------------------------------------------
# CRC-32C (Castagnoli), as libcsp 1.4 csp_crc32.c: reflected, init and xorout 0xFFFFFFFF.


def _crc32c_table() -> list[int]:
    table = []
    for n in range(256):
        c = n
        for _ in range(8):
            c = (c >> 1) ^ 0x82F63B78 if c & 1 else c >> 1
        table.append(c)
    return table


_CRC32C_TABLE = _crc32c_table()


def crc32c(data: bytes) -> int:
    """CRC-32C of ``data`` as ``csp_crc32_memory`` returns it (``b"123456789"`` gives
    ``0xE3069283``)."""
    crc = 0xFFFFFFFF
    table = _CRC32C_TABLE
    for b in data:
        crc = table[(crc ^ b) & 0xFF] ^ (crc >> 8)
    return crc ^ 0xFFFFFFFF


# ---------------------------------------------------------------------------------------
# The header.


@dataclass(frozen=True)
class Header:
    """The CSP 1.4 header: one 32-bit word ``prio<<30 | src<<25 | dst<<20 | dport<<14 |
    sport<<8 | flags``, big-endian on KISS and CAN."""

    prio: int
    src: int
    dst: int
    dport: int
    sport: int
    flags: int = 0

    def __post_init__(self) -> None:
        for name, value, top in (
            ("prio", self.prio, 3),
            ("src", self.src, 31),
            ("dst", self.dst, 31),
            ("dport", self.dport, 63),
            ("sport", self.sport, 63),
            ("flags", self.flags, 255),
        ):
            if not isinstance(value, int) or not 0 <= value <= top:
                raise ValueError(f"CSP header {name} {value!r} is outside 0..={top}")

    @property
    def word(self) -> int:
        """The header as one 32-bit integer."""
        return (
            self.prio << 30
            | self.src << 25
            | self.dst << 20
            | self.dport << 14
            | self.sport << 8
            | self.flags
        )

    def pack(self) -> bytes:
        """The 4 wire bytes (network order, as KISS and CAN send them)."""
        return struct.pack(">I", self.word)

    @classmethod
    def from_word(cls, word: int) -> Header:
        return cls(
            prio=word >> 30 & 0x3,
            src=word >> 25 & 0x1F,
            dst=word >> 20 & 0x1F,
            dport=word >> 14 & 0x3F,
            sport=word >> 8 & 0x3F,
            flags=word & 0xFF,
        )

    @classmethod
    def unpack(cls, b: bytes) -> Header:
        """The header in the first 4 bytes of ``b`` (network order)."""
        if len(b) < 4:
            raise ValueError(f"a CSP header is 4 bytes, got {len(b)}")
        return cls.from_word(struct.unpack(">I", bytes(b[:4]))[0])

    def reply(self, flags: int | None = None) -> Header:
        """The header of the reply to a request with this header: to its source address
        and port, from the port it came to, with its priority and (unless given) flags."""
        return Header(
            self.prio,
            self.dst,
            self.src,
            self.sport,
            self.dport,
            self.flags if flags is None else flags,
        )


@dataclass(frozen=True)
class Packet:
    """A CSP packet: its header and its data (without any CRC a link adds)."""

    header: Header
    data: bytes = field(default=b"")

    def to_bytes(self) -> bytes:
        """``header | data``."""
        return self.header.pack() + bytes(self.data)

    @classmethod
    def from_bytes(cls, b: bytes) -> Packet:
        return cls(Header.unpack(b), bytes(b[4:]))

    def with_csp_crc(self) -> Packet:
        """The packet as ``csp_send`` sends it with the CRC32 flag: the data followed by
        its CRC-32C, big-endian (libcsp 1.4 never covers the header)."""
        return Packet(self.header, bytes(self.data) + struct.pack(">I", crc32c(self.data)))

    def strip_csp_crc(self) -> Packet | None:
        """For a packet with the CRC32 flag: the data without its CRC, or None when the
        CRC is wrong or missing (libcsp drops such a packet). Without the flag: itself."""
        if not self.header.flags & FLAG_CRC32:
            return self
        d = self.data
        if len(d) < 4 or crc32c(d[:-4]) != struct.unpack(">I", d[-4:])[0]:
            return None
        return Packet(self.header, d[:-4])


# ---------------------------------------------------------------------------------------
# KISS, as libcsp 1.4 csp_if_kiss.c.

FEND, FESC, TFEND, TFESC = 0xC0, 0xDB, 0xDC, 0xDD
KISS_CMD_DATA = 0x00
#: libcsp 1.4's receive buffer: header, data and KISS CRC together.
KISS_MTU_LIBCSP14 = 256
#: This decoder's bound on one frame when no MTU is given (the twin's frames are far
#: smaller; the bound only keeps a stream without FENDs from growing a buffer forever).
KISS_MAX_FRAME = 65536


def kiss_encode(packet: Packet) -> bytes:
    """One KISS frame, as ``csp_kiss_tx``: ``FEND 00 escaped(header | data |
    CRC32C(data)) FEND``. The KISS CRC is always there and covers the data only."""
    data = bytes(packet.data)
    body = packet.header.pack() + data + struct.pack(">I", crc32c(data))
    out = bytearray([FEND, KISS_CMD_DATA])
    for b in body:
        if b == FEND:
            out += bytes([FESC, TFEND])
        elif b == FESC:
            out += bytes([FESC, TFESC])
        else:
            out.append(b)
    out.append(FEND)
    return bytes(out)


class KissDecoder:
    """Bytes in, packets out (KISS CRC checked and stripped), as ``csp_kiss_rx`` in
    libcsp 1.4: a frame starts at a FEND, the byte after it (the KISS command) is skipped
    unchecked, bytes outside frames are counted in ``discarded_bytes``, FESC followed by
    anything but TFEND/TFESC loses both bytes, and a frame shorter than header + CRC,
    with a bad CRC, or over ``mtu`` is dropped and counted in ``rx_errors``.

    One leniency, on purpose: a frame's closing FEND also opens the next one (libcsp 1.4
    loses a second frame that shares its FEND; the twin never sends one).

    ``mtu``: the largest frame body (header, data and CRC, unescaped) accepted;
    :data:`KISS_MTU_LIBCSP14` for libcsp 1.4's limit, None for :data:`KISS_MAX_FRAME`.
    """

    def __init__(self, mtu: int | None = None) -> None:
        self.mtu = KISS_MAX_FRAME if mtu is None else mtu
        self.rx_errors = 0
        self.discarded_bytes = 0
        self._buf = bytearray()
        self._in_frame = False
        self._skip_command = False
        self._escaped = False
        self._overflow = False

    def feed(self, chunk: bytes) -> list[Packet]:
        """Take bytes from the stream; return the packets they completed."""
        packets: list[Packet] = []
        for b in chunk:
            if b == FEND:
                if self._in_frame and (self._buf or self._overflow):
                    p = self._finish()
                    if p is not None:
                        packets.append(p)
                self._in_frame, self._skip_command, self._escaped = True, True, False
                self._overflow = False
                self._buf.clear()
            elif not self._in_frame:
                self.discarded_bytes += 1
            elif self._skip_command:
                self._skip_command = False
            elif self._escaped:
                self._escaped = False
                if b == TFEND:
                    self._put(FEND)
                elif b == TFESC:
                    self._put(FESC)
                # anything else after FESC: both bytes are dropped (libcsp 1.4)
            elif b == FESC:
                self._escaped = True
            else:
                self._put(b)
        return packets

    def _put(self, b: int) -> None:
        if len(self._buf) >= self.mtu:
            self._overflow = True
            return
        self._buf.append(b)

    def _finish(self) -> Packet | None:
        body = bytes(self._buf)
        if self._overflow or len(body) < 4 + 4:
            self.rx_errors += 1
            return None
        content, crc = body[:-4], struct.unpack(">I", body[-4:])[0]
        if crc32c(content[4:]) != crc:
            self.rx_errors += 1
            return None
        return Packet.from_bytes(content)


# ---------------------------------------------------------------------------------------
# libcsp 1.4's ZMQ hub (csp_if_zmqhub.c).

#: The most data libcsp 1.4 takes from one hub message (its 256-byte buffers).
ZMQ_HUB_MTU = 256


def zmq_encode(packet: Packet, via: int | None = None) -> bytes:
    """One hub message: ``via | header | data``. The header is the packet's memory as
    libcsp keeps it, the word little-endian on the hosts libcsp programs run on; ``via``
    (what subscribers filter on) is the destination unless given."""
    v = packet.header.dst if via is None else via
    return bytes([v]) + struct.pack("<I", packet.header.word) + bytes(packet.data)


def zmq_decode(msg: bytes) -> Packet | None:
    """The packet of a hub message, or None when it is shorter than 5 bytes or carries
    more than :data:`ZMQ_HUB_MTU` data bytes."""
    if len(msg) < 5 or len(msg) - 5 > ZMQ_HUB_MTU:
        return None
    word = struct.unpack("<I", bytes(msg[1:5]))[0]
    return Packet(Header.from_word(word), bytes(msg[5:]))
