#!/usr/bin/env python3
"""An outside CSP 1.4 node speaking libcsp 1.4's KISS format over TCP, written from the
wire spec (docs/protocol.md, libcsp v1.4 csp_if_kiss.c), not from the twin's code.

It joins a running twin (`m6p-twin run --kiss-listen ADDR`) and checks, byte for byte:
ping echoes from the FC and a payload (including payloads that need KISS escapes),
uptime (u32 big-endian seconds) and CMP ident (93 bytes). With --as 14 it joins the payload
CAN bus instead of the ground segment. With --garbage SECONDS it first sends random bytes
for that long, then checks that the twin still answers.

Exit 0 when every check passes; prints one line per check.
"""
import argparse
import os
import random
import socket
import sys
import time

FEND, FESC, TFEND, TFESC = 0xC0, 0xDB, 0xDC, 0xDD


def crc32c(data: bytes) -> int:
    """CRC-32C (Castagnoli), reflected, init/xorout 0xFFFFFFFF (libcsp csp_crc32.c)."""
    crc = 0xFFFFFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ (0x82F63B78 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


assert crc32c(b"123456789") == 0xE3069283


def header(prio, src, dst, dport, sport, flags=0) -> bytes:
    word = prio << 30 | src << 25 | dst << 20 | dport << 14 | sport << 8 | flags
    return word.to_bytes(4, "big")


def parse_header(b: bytes):
    w = int.from_bytes(b[:4], "big")
    return dict(prio=w >> 30, src=(w >> 25) & 31, dst=(w >> 20) & 31,
                dport=(w >> 14) & 63, sport=(w >> 8) & 63, flags=w & 255)


def kiss_frame(hdr: bytes, data: bytes) -> bytes:
    body = hdr + data + crc32c(data).to_bytes(4, "big")
    out = bytearray([FEND, 0x00])
    for b in body:
        if b == FEND:
            out += bytes([FESC, TFEND])
        elif b == FESC:
            out += bytes([FESC, TFESC])
        else:
            out.append(b)
    out.append(FEND)
    return bytes(out)


class KissReader:
    """libcsp 1.4 receiver semantics: every frame starts at a FEND, the command byte is
    skipped, escapes undone, the trailing CRC32C verified and stripped."""

    def __init__(self, sock):
        self.sock = sock
        self.buf = bytearray()

    def frames(self, timeout):
        deadline = time.monotonic() + timeout
        while True:
            while True:
                try:
                    start = self.buf.index(FEND)
                except ValueError:
                    self.buf.clear()
                    break
                del self.buf[:start]
                # skip repeated FENDs
                while len(self.buf) > 1 and self.buf[1] == FEND:
                    del self.buf[0]
                try:
                    end = self.buf.index(FEND, 1)
                except ValueError:
                    break
                raw = bytes(self.buf[2:end])  # skip FEND and command byte
                del self.buf[:end + 1]
                body = bytearray()
                i = 0
                while i < len(raw):
                    if raw[i] == FESC and i + 1 < len(raw):
                        body.append(FEND if raw[i + 1] == TFEND else FESC)
                        i += 2
                    else:
                        body.append(raw[i])
                        i += 1
                if len(body) < 8:
                    continue
                data, crc = bytes(body[4:-4]), int.from_bytes(body[-4:], "big")
                if crc32c(data) != crc:
                    print("  (frame with bad CRC ignored)")
                    continue
                yield parse_header(body), data
            left = deadline - time.monotonic()
            if left <= 0:
                return
            self.sock.settimeout(left)
            try:
                chunk = self.sock.recv(4096)
            except socket.timeout:
                return
            if not chunk:
                raise RuntimeError("twin closed the connection")
            self.buf += chunk


class Peer:
    def __init__(self, addr, me):
        host, port = addr.rsplit(":", 1)
        self.sock = socket.create_connection((host, int(port)), timeout=5)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.reader = KissReader(self.sock)
        self.me = me
        self.sport = 40

    def request(self, dst, dport, data, timeout=3.0):
        self.sport = 32 + (self.sport - 31) % 32
        self.sock.sendall(kiss_frame(header(2, self.me, dst, dport, self.sport), data))
        for h, d in self.reader.frames(timeout):
            if h["src"] == dst and h["dport"] == self.sport and h["sport"] == dport and h["dst"] == self.me:
                return h, d
        return None, None

    def ask(self, dst, dport, cmd, data=b"", timeout=3.0):
        """An ICD request `cmd | data` (ICD 1.8): (result, reply data after `cmd | result`),
        or (None, what came back) when no reply to that command came."""
        h, d = self.request(dst, dport, bytes([cmd]) + data, timeout)
        if d is None or len(d) < 2 or d[0] != cmd:
            return None, d
        return d[1], d[2:]


class Checks:
    """Prints one PASS/FAIL line per check and counts the failures."""

    def __init__(self):
        self.failures = 0

    def __call__(self, name, ok, detail=""):
        print(("PASS " if ok else "FAIL ") + name + (": " + detail if detail else ""))
        self.failures += 0 if ok else 1


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--as", dest="me", type=int, default=17)
    ap.add_argument("--targets", default="3,12")
    ap.add_argument("--garbage", type=float, default=0.0)
    a = ap.parse_args()
    check = Checks()

    if a.garbage > 0:
        host, port = a.connect.rsplit(":", 1)
        g = socket.create_connection((host, int(port)))
        rng = random.Random(1234)
        sent = 0
        end = time.monotonic() + a.garbage
        while time.monotonic() < end:
            chunk = bytes(rng.getrandbits(8) for _ in range(4096))
            g.sendall(chunk)
            sent += len(chunk)
        g.close()
        print(f"sent {sent} random bytes in {a.garbage:.0f} s")

    p = Peer(a.connect, a.me)
    for dst in [int(x) for x in a.targets.split(",")]:
        for size, payload in [(4, bytes(range(4))), (64, bytes(i % 256 for i in range(64))),
                              (8, bytes([0xC0, 0xDB, 0xDC, 0xDD, 0xC0, 0xC0, 0xDB, 0xDB])),
                              (200, bytes(i % 256 for i in range(200)))]:
            h, d = p.request(dst, 1, payload)
            check(f"ping {dst} size {size}", d == payload,
                  "no reply" if d is None else f"got {len(d)} bytes, prio {h['prio']} flags {h['flags']}")
        h, d = p.request(dst, 6, b"")
        check(f"uptime {dst}", d is not None and len(d) == 4 and int.from_bytes(d, "big") < 24 * 3600,
              "no reply" if d is None else d.hex())
        h, d = p.request(dst, 0, b"\x00\x01")
        ok = d is not None and len(d) == 93 and d[:2] == b"\xff\x01" and d[21] == 0
        check(f"ident {dst}", ok, "no reply" if d is None else repr(d[2:22].rstrip(b"\0")))
    sys.exit(1 if check.failures else 0)


if __name__ == "__main__":
    main()
