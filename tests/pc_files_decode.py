#!/usr/bin/env python3
"""An independent client of the PC's buffer files (port 13), written from docs/protocol.md
("Buffer files") and ICD 3.1.5, not from the twin's code. The framing is tests/kiss_peer.py's.

As ground node --as (17), while payload --payload (13) pushes into its buffer file:

- FLIST 1: `count u8` then 18-byte entries `<BBIIQ` (payload, session, size, capacity,
  head offset); FSTAT 2 of the payload: one entry, and the file grows between two reads;
- FREAD 3 `<BQB` (payload, offset, length 1-200): the reply `<Q` offset served, then the
  bytes; an overlapping second read gives the same bytes; an offset before the head is
  served from the head; past the end, no bytes;
- FDELETE 4: `<I` bytes removed, at least what FSTAT showed; the head moves past them;
- failure replies `cmd 00`: an unknown file, a length of 0 or 201, a wrong length, and any
  request from a payload (--as-payload, 14: ICD 3.1.5 denies it the file system).

Prints `READ offset hex` for each read so that the caller can check the bytes against what
the payload sent. Exit 0 when every check passes; prints one line per check.
"""
import argparse
import os
import struct
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from kiss_peer import Checks, Peer  # noqa: E402

PC, PORT_FILES = 6, 13
STAT = struct.Struct("<BBIIQ")
READ = struct.Struct("<BQB")
assert (STAT.size, READ.size) == (18, 10)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--as", dest="me", type=int, default=17)
    ap.add_argument("--payload", type=int, default=13)
    ap.add_argument("--session", type=int, default=2)
    ap.add_argument("--as-payload", type=int, default=14)
    a = ap.parse_args()
    check = Checks()
    g = Peer(a.connect, a.me)

    def ask(peer, cmd, data=b""):
        return peer.ask(PC, PORT_FILES, cmd, data, timeout=5.0)

    def stat():
        res, d = ask(g, 2, bytes([a.payload]))
        return STAT.unpack(d) if res == 1 and len(d) == STAT.size else None

    def read(offset, length):
        res, d = ask(g, 3, READ.pack(a.payload, offset, length))
        if res != 1 or d is None or len(d) < 8:
            return None, None
        served = struct.unpack("<Q", d[:8])[0]
        print(f"READ {served} {d[8:].hex()}", flush=True)
        return served, d[8:]

    time.sleep(1.0)
    res, d = ask(g, 1)
    ok = res == 1 and len(d) >= 1 and len(d) == 1 + d[0] * STAT.size
    check("FLIST is a count and 18-byte entries", ok, f"result {res} data {d!r}")
    entries = [STAT.unpack_from(d, 1 + i * STAT.size) for i in range(d[0])] if ok else []
    mine = [e for e in entries if e[0] == a.payload]
    check(f"FLIST lists payload {a.payload}'s file of session {a.session}",
          len(mine) == 1 and mine[0][1] == a.session, f"{entries}")

    s1 = stat()
    check("FSTAT is 18 bytes and holds pushed bytes", s1 is not None and s1[2] > 0, f"{s1}")
    time.sleep(1.0)
    s2 = stat()
    check("the file grows as the payload pushes", s1 and s2 and s2[2] + s2[4] > s1[2] + s1[4],
          f"{s1} -> {s2}")
    head, size = s2[4], s2[2]

    o1, b1 = read(head, 200)
    check("FREAD at the head serves 200 bytes from there", o1 == head and len(b1) == 200,
          f"offset {o1} len {None if b1 is None else len(b1)}")
    o2, b2 = read(head + 100, 150)
    check("an overlapping FREAD gives the same bytes", o2 == head + 100 and b2[:100] == b1[100:],
          f"offset {o2}")
    o4, b4 = read(head + size + 10_000_000, 10)
    check("past the end: the end offset and no bytes", o4 is not None and o4 >= head + size and b4 == b"",
          f"offset {o4} data {b4!r}")

    s3 = stat()
    res, d = ask(g, 4, bytes([a.payload]))
    deleted = struct.unpack("<I", d)[0] if res == 1 and len(d) == 4 else None
    check("FDELETE answers the bytes removed", deleted is not None and deleted >= s3[2],
          f"result {res} data {d!r}, size was {s3[2]}")
    s4 = stat()
    check("after FDELETE the head is past the deleted bytes",
          s4 is not None and deleted is not None and s4[4] >= s3[4] + deleted, f"{s3} -> {s4}")
    o3, b3 = read(0, 10)
    check("an offset before the head is served from the head",
          o3 is not None and s4 is not None and o3 >= s4[4], f"offset {o3}, head {s4 and s4[4]}")

    for name, cmd, data in (("FSTAT of a file that does not exist", 2, bytes([15])),
                            ("FREAD of 0 bytes", 3, READ.pack(a.payload, 0, 0)),
                            ("FREAD of 201 bytes", 3, READ.pack(a.payload, 0, 201)),
                            ("FREAD with a short request", 3, READ.pack(a.payload, 0, 1)[:9]),
                            ("FLIST with data", 1, b"\x00")):
        res, d = ask(g, cmd, data)
        check(f"{name} gets the failure reply", res == 0 and d == b"", f"result {res} {d!r}")
    pl = Peer(a.connect, a.as_payload)
    for name, cmd, data in (("FLIST", 1, b""), ("FSTAT", 2, bytes([a.payload])),
                            ("FDELETE", 4, bytes([a.payload]))):
        res, d = ask(pl, cmd, data)
        check(f"payload {a.as_payload}'s {name} is refused", res == 0 and d == b"",
              f"result {res} {d!r}")
    check.icd(g)
    sys.exit(1 if check.failures else 0)


if __name__ == "__main__":
    main()
