#!/usr/bin/env python3
"""A payload of the M6P written outside the twin, in plain Python (standard library only).

It connects to the twin over TCP, speaks KISS and CSP 1.4 exactly as libcsp 1.4 does, and
takes the place of payload 12 on the payload CAN bus. It then does what ICD 3.1.8.2 asks of
a payload in a polling session of the payload controller (PC, CSP 6):

    SYNC  request  01 | message (0-128 bytes)   reply  01 01 | message (the same bytes)
    POLL  request  02 | frameSize (1 byte)      reply  02 01 | data (1 to frameSize bytes)

(a request is `command | data`, a reply `command | result | data`, result 1 = success,
0 = failure; INTERPRETATION.md section 2). Replies go back to the request's source address
and port, from the port the request came to, with the request's priority and flags. It also
answers CSP pings (port 1), as any libcsp node does.

Its data is a deterministic stream (`frame_data`): frame number `seq` is `seq` as u16
little-endian followed by a byte counter starting at `seq`, and its length cycles through
all, two thirds and one third of the frameSize the PC asks for. Every data byte it puts in a
POLL reply is written to the file given with `--sent`, in order, so that what the twin
downlinked over the S-band can be compared with it byte for byte.

It stops when the session is over (no POLL for `--idle` seconds after the first one), when
the twin closes the connection (end of its run), or after `--seconds`. Exit status: 0 when
it served a session (at least one SYNC and one POLL) and received no damaged frame, 1
otherwise, 2 when it could not connect.

Run it against the twin (from the repository root; examples/README.md has the scenario):

    # 1. the scenario: a KISS/TCP server for address 12 and a SETUP of session 1 at t = 2 s
    #    (copy the `cat > /tmp/outside_payload.toml` block of examples/README.md)
    # 2. build the twin, then start the payload: it keeps trying to connect for --wait s
    cargo build --release -p m6p-twin
    python3 examples/outside_payload.py --connect 127.0.0.1:52001 --sent /tmp/sent.bin &
    # 3. the twin, which writes what reached the ground to /tmp/outside_payload.downlink/
    target/release/m6p-twin run /tmp/outside_payload.toml
    wait
    cmp /tmp/sent.bin /tmp/outside_payload.downlink/session-1-run1.bin && echo identical

The test crates/twin/tests/outside_payload.rs runs that scenario with this script and
checks the downlink byte for byte (`cargo test -p m6p-twin --test outside_payload`).

Wire facts used here (docs/protocol.md, libcsp 1.4 csp_if_kiss.c and csp_crc32.c):
- CSP header: one 32-bit big-endian word prio<<30 | src<<25 | dst<<20 | dport<<14 |
  sport<<8 | flags.
- KISS frame: FEND 0x00 escaped(header | data | CRC32C(data) big-endian) FEND, with
  C0 -> DB DC and DB -> DB DD. The KISS CRC is always there and covers the data only.
- CSP CRC flag (0x01): the data of the packet itself ends with a CRC32C of the rest; it is
  checked and stripped on arrival, and added to the reply (which mirrors the flags).
"""
import argparse
import socket
import struct
import sys
import time

# ---------------------------------------------------------------------------------------
# CRC-32C (Castagnoli), as libcsp 1.4 csp_crc32.c: reflected, init and xorout 0xFFFFFFFF.

def _crc32c_table():
    table = []
    for n in range(256):
        c = n
        for _ in range(8):
            c = (c >> 1) ^ 0x82F63B78 if c & 1 else c >> 1
        table.append(c)
    return table


_CRC32C_TABLE = _crc32c_table()


def crc32c(data: bytes) -> int:
    crc = 0xFFFFFFFF
    for b in data:
        crc = _CRC32C_TABLE[(crc ^ b) & 0xFF] ^ (crc >> 8)
    return crc ^ 0xFFFFFFFF


assert crc32c(b"123456789") == 0xE3069283  # the standard check value

# ---------------------------------------------------------------------------------------
# CSP 1.4 header.

FLAG_CRC32 = 0x01


def csp_header_pack(prio, src, dst, dport, sport, flags=0) -> bytes:
    """The 4-byte header: prio[31:30] src[29:25] dst[24:20] dport[19:14] sport[13:8]
    flags[7:0], big-endian."""
    word = prio << 30 | src << 25 | dst << 20 | dport << 14 | sport << 8 | flags
    return struct.pack(">I", word)


def csp_header_unpack(b: bytes) -> dict:
    (word,) = struct.unpack(">I", b[:4])
    return {
        "prio": word >> 30,
        "src": (word >> 25) & 0x1F,
        "dst": (word >> 20) & 0x1F,
        "dport": (word >> 14) & 0x3F,
        "sport": (word >> 8) & 0x3F,
        "flags": word & 0xFF,
    }

# ---------------------------------------------------------------------------------------
# KISS, as libcsp 1.4 csp_if_kiss.c.

FEND, FESC, TFEND, TFESC = 0xC0, 0xDB, 0xDC, 0xDD
KISS_CMD_DATA = 0x00


def kiss_encode(packet: bytes) -> bytes:
    """One KISS frame for a CSP packet (`header | data`): the data's CRC32C is appended
    big-endian, everything after the command byte is escaped."""
    data = packet[4:]
    body = packet + struct.pack(">I", crc32c(data))
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
    """Bytes from the socket in, CSP packets (`header | data`, KISS CRC checked and
    stripped) out. As libcsp 1.4: a frame starts at a FEND, the command byte after it is
    skipped, bytes outside frames are ignored, FESC followed by anything but TFEND/TFESC
    loses both bytes, a frame shorter than header + CRC or with a bad CRC is dropped (and
    counted). One leniency: a frame's closing FEND may also open the next one (libcsp 1.4
    wants a FEND of its own before each frame, which the twin always sends)."""

    def __init__(self):
        self.buf = bytearray()
        self.in_frame = False
        self.escaped = False
        self.skip_command = False
        self.bad_frames = 0

    def kiss_decode(self, chunk: bytes) -> list:
        packets = []
        for b in chunk:
            if b == FEND:
                if self.in_frame and self.buf:
                    packet = self._finish(bytes(self.buf))
                    if packet is not None:
                        packets.append(packet)
                # Every FEND (re)starts a frame; the next byte is the command byte.
                self.in_frame, self.skip_command, self.escaped = True, True, False
                self.buf.clear()
            elif not self.in_frame:
                continue  # noise between frames
            elif self.skip_command:
                self.skip_command = False
            elif self.escaped:
                self.escaped = False
                if b == TFEND:
                    self.buf.append(FEND)
                elif b == TFESC:
                    self.buf.append(FESC)
                # anything else after FESC: both bytes are dropped (libcsp 1.4)
            elif b == FESC:
                self.escaped = True
            else:
                self.buf.append(b)
        return packets

    def _finish(self, body: bytes):
        if len(body) < 4 + 4:
            self.bad_frames += 1
            return None
        packet, crc = body[:-4], struct.unpack(">I", body[-4:])[0]
        if crc32c(packet[4:]) != crc:
            self.bad_frames += 1
            return None
        return packet

# ---------------------------------------------------------------------------------------
# The payload: SYNC, POLL, ping.

CMD_SYNC, CMD_POLL = 0x01, 0x02
RESULT_OK, RESULT_FAIL = 0x01, 0x00
SYNC_MAX_BYTES = 128  # ICD 3.1.8.2 table 5: the sync message is 0-128 bytes
PORT_PING = 1  # CSP service port (libcsp csp_service_handler)


def frame_data(seq: int, frame_size: int) -> bytes:
    """Data frame number `seq` for a POLL of `frame_size` bytes: `seq` as u16
    little-endian, then a byte counter starting at `seq`; its length cycles through
    frame_size, 2/3 and 1/3 of it (at least 1), so that the twin sees replies shorter than
    asked for as well. The counter goes through every byte value, including the KISS
    special bytes C0 and DB."""
    length = max(1, frame_size - (seq % 3) * (frame_size // 3))
    frame = struct.pack("<H", seq & 0xFFFF) + bytes((seq + i) & 0xFF for i in range(length))
    return frame[:length]


class Payload:
    """The payload's state: the next frame number, what it sent, what it served."""

    def __init__(self, addr: int, port: int, sent_file):
        self.addr = addr
        self.port = port
        self.sent_file = sent_file
        self.seq = 0
        self.syncs = 0
        self.polls = 0
        self.bytes_sent = 0
        self.refused = 0
        self.last_poll = None

    def handle_sync(self, message: bytes) -> bytes:
        """SYNC: echo the message, `01 01 | message`."""
        if len(message) > SYNC_MAX_BYTES:
            self.refused += 1
            return bytes([CMD_SYNC, RESULT_FAIL])
        self.syncs += 1
        print(f"SYNC {message!r}: acknowledged", flush=True)
        return bytes([CMD_SYNC, RESULT_OK]) + message

    def handle_poll(self, args: bytes) -> bytes:
        """POLL: the next data frame, `02 01 | data`, at most frameSize bytes."""
        if len(args) != 1 or args[0] == 0:
            self.refused += 1
            return bytes([CMD_POLL, RESULT_FAIL])
        data = frame_data(self.seq, args[0])
        self.seq += 1
        self.polls += 1
        self.bytes_sent += len(data)
        self.last_poll = time.monotonic()
        if self.sent_file is not None:
            self.sent_file.write(data)
            self.sent_file.flush()
        return bytes([CMD_POLL, RESULT_OK]) + data

    def handle_request(self, data: bytes) -> bytes:
        """A request to the payload port: `command | data`; unknown or empty: failure."""
        if not data:
            self.refused += 1
            return bytes([0x00, RESULT_FAIL])
        command, args = data[0], data[1:]
        if command == CMD_SYNC:
            return self.handle_sync(args)
        if command == CMD_POLL:
            return self.handle_poll(args)
        self.refused += 1
        return bytes([command, RESULT_FAIL])

    def handle_packet(self, packet: bytes):
        """One CSP packet in; the reply packet out (or None)."""
        h = csp_header_unpack(packet)
        data = packet[4:]
        if h["dst"] != self.addr:
            return None
        if h["flags"] & FLAG_CRC32:
            if len(data) < 4 or crc32c(data[:-4]) != struct.unpack(">I", data[-4:])[0]:
                print(f"dropped a packet with a bad CSP CRC from {h['src']}", flush=True)
                return None
            data = data[:-4]
        if h["dport"] == self.port:
            reply = self.handle_request(data)
        elif h["dport"] == PORT_PING:
            reply = data
        else:
            return None  # no socket bound on that port: libcsp drops it
        if h["flags"] & FLAG_CRC32:
            reply += struct.pack(">I", crc32c(reply))
        # To the request's source address and port, from the port it came to, with its
        # priority and flags.
        head = csp_header_pack(h["prio"], self.addr, h["src"], h["sport"], h["dport"], h["flags"])
        return head + reply

# ---------------------------------------------------------------------------------------
# The connection.


def connect(addr: str, wait_s: float) -> socket.socket:
    """Connect to HOST:PORT, retrying every 100 ms for up to `wait_s` seconds (so the
    payload can be started before the twin)."""
    host, port = addr.rsplit(":", 1)
    deadline = time.monotonic() + wait_s
    while True:
        try:
            sock = socket.create_connection((host, int(port)), timeout=1.0)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            return sock
        except OSError:
            if time.monotonic() >= deadline:
                raise
            time.sleep(0.1)


def serve(sock, payload: Payload, decoder: KissDecoder, idle_s: float, seconds):
    """Answer requests until the session is over; returns why it stopped."""
    start = time.monotonic()
    sock.settimeout(0.1)
    while True:
        now = time.monotonic()
        if seconds is not None and now - start >= seconds:
            return f"{seconds} s elapsed"
        if payload.last_poll is not None and now - payload.last_poll >= idle_s:
            return f"no POLL for {idle_s} s: the session is over"
        try:
            chunk = sock.recv(4096)
        except socket.timeout:
            continue
        if not chunk:
            return "the twin closed the connection"
        for packet in decoder.kiss_decode(chunk):
            reply = payload.handle_packet(packet)
            if reply is not None:
                sock.sendall(kiss_encode(reply))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--connect", default="127.0.0.1:52001",
                    help="the twin's KISS/TCP server, HOST:PORT (default %(default)s)")
    ap.add_argument("--addr", type=int, default=12,
                    help="this payload's CSP address, 12-15 (default %(default)s)")
    ap.add_argument("--port", type=int, default=10,
                    help="the SYNC/POLL port (default %(default)s)")
    ap.add_argument("--sent", metavar="FILE",
                    help="write every data byte sent in POLL replies to FILE (binary, in order)")
    ap.add_argument("--idle", type=float, default=3.0,
                    help="stop after this many seconds without a POLL (default %(default)s)")
    ap.add_argument("--seconds", type=float, default=None,
                    help="stop after this many seconds whatever happens")
    ap.add_argument("--wait", type=float, default=60.0,
                    help="keep trying to connect for this long (default %(default)s s)")
    a = ap.parse_args()

    try:
        sock = connect(a.connect, a.wait)
    except OSError as e:
        print(f"cannot connect to {a.connect}: {e}", file=sys.stderr)
        return 2
    print(f"connected to {a.connect} as CSP {a.addr}, serving port {a.port}", flush=True)
    sent_file = open(a.sent, "wb") if a.sent else None
    payload = Payload(a.addr, a.port, sent_file)
    decoder = KissDecoder()
    try:
        why = serve(sock, payload, decoder, a.idle, a.seconds)
    except OSError as e:
        why = f"connection error: {e}"
    finally:
        sock.close()
        if sent_file is not None:
            sent_file.close()
    print(f"stopped ({why}): {payload.syncs} SYNC, {payload.polls} POLL, "
          f"{payload.bytes_sent} data bytes sent, {payload.refused} refused, "
          f"{decoder.bad_frames} damaged frames", flush=True)
    served = payload.syncs > 0 and payload.polls > 0
    return 0 if served and decoder.bad_frames == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
