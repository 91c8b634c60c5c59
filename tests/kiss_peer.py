#!/usr/bin/env python3
"""An outside CSP 1.4 node speaking libcsp 1.4's KISS format over TCP, on the project's
Python package (`m6p`: its framing is written from the wire spec, docs/protocol.md and
libcsp v1.4 csp_if_kiss.c, and checked against libcsp 1.4's own vectors; not the twin's
code). The other decoders here build on its `Peer` and `Checks`.

It joins a running twin (`m6p-twin run --kiss-listen ADDR`) and checks, byte for byte:
ping echoes from the FC and a payload (including payloads that need KISS escapes),
uptime (u32 big-endian seconds) and CMP ident (93 bytes). With --as 14 it joins the payload
CAN bus instead of the ground segment. With --garbage SECONDS it first sends random bytes
for that long, then checks that the twin still answers.

Exit 0 when every check passes; prints one line per check.
"""
import argparse
import dataclasses
import os
import random
import socket
import sys
import time

try:
    import m6p  # noqa: F401
except ImportError:  # a checkout without `pip install ./python`
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python", "src"))

from m6p.csp import Header, Packet  # noqa: E402
from m6p.icd import Icd  # noqa: E402
from m6p.links import KissTcp  # noqa: E402


class Peer:
    """A CSP node over KISS/TCP (the `m6p` package's framing, checked against libcsp
    1.4's vectors) that waits for one reply at a time, as these checks want it.

    Every successful ICD reply `ask` gets is also decoded with the package's generated
    ICD (`m6p.icd`, from the twin's `icd --json`): `icd_problems` lists the replies it
    does not decode, and `Checks.agree` compares a decoder's own reading, written from
    the ICD document, with the package's."""

    def __init__(self, addr, me):
        self.link = KissTcp(addr, connect_timeout_s=5.0)
        self.me = me
        self.sport = 40
        self.icd = Icd.load()
        self.icd_decoded = 0
        self.icd_problems = []
        self.last_reply = None

    def send(self, dst, dport, sport, data, flags=0, prio=2):
        """One packet as it is (no CSP CRC added, whatever the flags)."""
        self.link.send(Packet(Header(prio, self.me, dst, dport, sport, flags), bytes(data)))

    def frames(self, timeout):
        """Every packet for the next `timeout` seconds: (header fields, data)."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return
            p = self.link.recv(left)
            if p is None:
                return
            yield dataclasses.asdict(p.header), p.data

    def request(self, dst, dport, data, timeout=3.0):
        self.sport = 32 + (self.sport - 31) % 32
        self.send(dst, dport, self.sport, data)
        for h, d in self.frames(timeout):
            if h["src"] == dst and h["dport"] == self.sport and h["sport"] == dport and h["dst"] == self.me:
                return h, d
        return None, None

    def ask(self, dst, dport, cmd, data=b"", timeout=3.0):
        """An ICD request `cmd | data` (ICD 1.8): (result, reply data after `cmd | result`),
        or (None, what came back) when no reply to that command came."""
        h, d = self.request(dst, dport, bytes([cmd]) + data, timeout)
        self.last_reply = None
        if d is None or len(d) < 2 or d[0] != cmd:
            return None, d
        command = self.icd.on_port(dst, dport, cmd)
        if d[1] == 1 and command is not None:
            try:
                self.last_reply = command.decode_reply(d)
                self.icd_decoded += 1
            except ValueError as e:
                self.icd_problems.append(f"{command.full_name}: {e}")
        return d[1], d[2:]


class Checks:
    """Prints one PASS/FAIL line per check and counts the failures."""

    def __init__(self):
        self.failures = 0

    def __call__(self, name, ok, detail=""):
        print(("PASS " if ok else "FAIL ") + name + (": " + detail if detail else ""))
        self.failures += 0 if ok else 1

    def agree(self, name, hand, reply):
        """This decoder's own values (`hand`, in wire order) are the package's decoding
        of the same reply (`reply`, Peer.last_reply), value for value."""
        theirs = None if reply is None else [leaf.value for leaf in reply.leaves()]
        same = theirs == list(hand)
        self(f"{name}: the m6p package's decoding agrees ({len(hand)} values)", same,
             "" if same else f"here {list(hand)}, m6p {theirs}")

    def icd(self, peer):
        """The package decoded every successful ICD reply this peer got."""
        self(f"the m6p package decodes the {peer.icd_decoded} ICD replies",
             peer.icd_decoded > 0 and not peer.icd_problems, "; ".join(peer.icd_problems))


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
        if 12 <= a.me <= 15 and 1 <= dst <= 6:
            # ICD 4.1: a payload gets a platform node's ping and uptime, no other service.
            check(f"ident {dst} not answered to a payload", d is None, f"got {d!r}")
        else:
            ok = d is not None and len(d) == 93 and d[:2] == b"\xff\x01" and d[21] == 0
            check(f"ident {dst}", ok, "no reply" if d is None else repr(d[2:22].rstrip(b"\0")))
    sys.exit(1 if check.failures else 0)


if __name__ == "__main__":
    main()
