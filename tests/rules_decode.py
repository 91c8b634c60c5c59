#!/usr/bin/env python3
"""The rules a payload and the ground live under, checked from outside a running twin and
written from the M6P Software ICD (sections 1.6, 3.1.1, 3.1.3, 4.1, 4.2.2) and libcsp 1.4's
csp_route.c, not from the twin's code. The framing is tests/kiss_peer.py's.

As ground node --as (17 by default) and, on a second connection of the same link, as
payload --payload (14):

- ICD 1.6 (libcsp 1.4 built without XTEA, HMAC and RDP): a ping flagged RDP (0x02), XTEA
  (0x04) or HMAC (0x08) to every node of --nodes gets no reply, while the same ping unflagged
  is echoed;
- ICD 4.1 and 3.1.1: the payload's TMGEN, TMATP, TMACD, TMSENS, RTCSTMGET and ping are
  answered; its TMALL, TMRAWSENS, RTCSTMSET, ATCMDSET and the PC's SETUP and ABORT get the
  failure reply `cmd 00`; the PC's STATUS is answered;
- ICD 3.1.3: after an RTCSTMSET of +--rtc-step seconds, a SETUP of session --session timed
  --lead seconds after RTCSTMGET goes PENDING and then ACTIVE about --lead seconds later
  (the PC's clock follows the FC's RTC). It prints `SETUP timestamp T` for the caller, who
  knows the simulated instants.

Exit 0 when every check passes; prints one line per check.
"""
import argparse
import os
import struct
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from kiss_peer import Checks, Peer  # noqa: E402

FC, PC = 3, 6
PORT_TM, PORT_RTC, PORT_ATC, PORT_PING = 10, 11, 12, 1
PC_CONTROL = 10
RDP, XTEA, HMAC = 0x02, 0x04, 0x08
SETUP = struct.Struct("<BIHHB")  # ICD 3.1.3, then the sync message


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--as", dest="me", type=int, default=17)
    ap.add_argument("--payload", type=int, default=14)
    ap.add_argument("--nodes", default="1,2,3,4,5,6,12,13")
    ap.add_argument("--rtc-step", type=int, default=1000)
    ap.add_argument("--session", type=int, default=1)
    ap.add_argument("--lead", type=int, default=4)
    ap.add_argument("--quiet", type=float, default=3.0)
    a = ap.parse_args()
    check = Checks()
    ground = Peer(a.connect, a.me)

    # ICD 1.6: flagged pings (each from a port of its own), every frame that comes back in
    # the next --quiet seconds kept (the whole burst's air time and back is about 1 s), then
    # the same ping unflagged, which every node echoes.
    nodes = [int(x) for x in a.nodes.split(",")]
    flagged = {}
    sport = 40
    for dst in nodes:
        for name, flag in (("RDP", RDP), ("XTEA", XTEA), ("HMAC", HMAC)):
            flagged[sport] = (dst, name)
            ground.send(dst, PORT_PING, sport, b"flag", flags=flag)
            sport += 1
    back = list(ground.frames(a.quiet))
    for sp, (dst, name) in sorted(flagged.items()):
        got = [d for h, d in back if h["dport"] == sp]
        check(f"{name}-flagged ping to {dst} is not answered", not got, f"replies {got!r}")
    for dst in nodes:
        h, d = ground.request(dst, PORT_PING, b"flag", timeout=5.0)
        check(f"the same ping unflagged to {dst} is echoed", d == b"flag", f"got {d!r}")

    # ICD 4.1 (the stars) and 3.1.1 (the session configuration is the mission's).
    pl = Peer(a.connect, a.payload)

    def ask(peer, dst, port, cmd, data=b""):
        return peer.ask(dst, port, cmd, data, timeout=5.0)

    h, d = pl.request(FC, PORT_PING, b"from a payload", timeout=5.0)
    check(f"payload {a.payload}'s ping to the FC is echoed", d == b"from a payload", f"{d!r}")
    for name, port, cmd, size in (("TMGEN", PORT_TM, 1, 16), ("TMATP", PORT_TM, 2, 60),
                                  ("TMACD", PORT_TM, 3, 19), ("TMSENS", PORT_TM, 4, 70),
                                  ("RTCSTMGET", PORT_RTC, 2, 4)):
        res, d = ask(pl, FC, port, cmd)
        check(f"payload's {name} is answered ({size} bytes)", res == 1 and len(d) == size,
              f"result {res} data {d!r}")
    # The RTCSTMSET asks for the time the RTC reads, so that even if it were taken it would
    # not move the clock the session check below reads.
    res, d = ask(pl, FC, PORT_RTC, 2)
    rtc = struct.unpack("<I", d)[0] if res == 1 and len(d) == 4 else 0
    for name, port, cmd, data in (("TMALL", PORT_TM, 6, b""), ("TMRAWSENS", PORT_TM, 5, b""),
                                  ("RTCSTMSET", PORT_RTC, 1, struct.pack("<I", rtc)),
                                  ("ATCMDSET", PORT_ATC, 6, bytes([3]))):
        res, d = ask(pl, FC, port, cmd, data)
        check(f"payload's {name} gets the failure reply", res == 0 and d == b"",
              f"result {res} data {d!r}")
    res, d = ask(pl, PC, PC_CONTROL, 1, SETUP.pack(a.session, 0, 5, 0, 64))
    check("payload's SETUP gets the failure reply", res == 0 and d == b"", f"result {res} {d!r}")
    res, d = ask(pl, PC, PC_CONTROL, 3, bytes([a.session]))
    check("payload's ABORT gets the failure reply", res == 0 and d == b"", f"result {res} {d!r}")
    res, d = ask(pl, PC, PC_CONTROL, 2, bytes([a.session]))
    check("payload's STATUS is answered", res == 1 and d is not None and len(d) >= 11,
          f"result {res} {d!r}")
    res, d = ask(pl, PC, PC_CONTROL, 2, bytes([a.session]))
    state = d[1] if res == 1 and d else None
    check("the payload's SETUP changed nothing (NOT ACTIVE)", state == 0, f"state {state}")

    # ICD 3.1.3: the session's timestamp is read against the platform's time.
    res, d = ask(ground, FC, PORT_RTC, 2)
    (r0,) = struct.unpack("<I", d) if res == 1 else (0,)
    res, d = ask(ground, FC, PORT_RTC, 1, struct.pack("<I", r0 + a.rtc_step))
    check(f"RTCSTMSET +{a.rtc_step} s succeeds", res == 1 and d == b"", f"result {res} {d!r}")
    res, d = ask(ground, FC, PORT_RTC, 2)
    (r1,) = struct.unpack("<I", d) if res == 1 else (0,)
    check(f"RTCSTMGET reads {a.rtc_step} s on", r1 - r0 - a.rtc_step in (0, 1), f"{r0} -> {r1}")
    t = r1 + a.lead
    res, d = ask(ground, PC, PC_CONTROL, 1, SETUP.pack(a.session, t, 5, 0, 64))
    check("SETUP timed from RTCSTMGET is accepted", res == 1, f"result {res} {d!r}")
    print(f"SETUP timestamp {t}", flush=True)
    states = []
    deadline = time.monotonic() + a.lead + 4
    while time.monotonic() < deadline:
        res, d = ask(ground, PC, PC_CONTROL, 2, bytes([a.session]))
        s = d[1] if res == 1 and d else None
        if not states or states[-1] != s:
            states.append(s)
        if s == 2:
            break
        time.sleep(0.2)
    check("the session goes PENDING, then ACTIVE", states[:1] == [1] and states[-1:] == [2],
          f"states {states}")
    check.icd(ground)
    sys.exit(1 if check.failures else 0)


if __name__ == "__main__":
    main()
