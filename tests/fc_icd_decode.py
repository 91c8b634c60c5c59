#!/usr/bin/env python3
"""An independent decoder of the flight computer's ICD replies, written from the M6P
Software ICD tables 4.2.1-4.2.3 and shared/icd/INTERPRETATION.md sections 2, 4 and 5 (and
docs/protocol.md "FC ports" for the twin's own TMALL layout), not from the twin's code.

It joins a running twin over KISS/TCP as a ground node (default 16; the framing is
tests/kiss_peer.py's, itself written from libcsp 1.4) and asks the FC (node 3):

- port 10 TMGEN 1: 16 bytes `<IIIBBbB` (rtc, uptime, global on time, mode, state, MCU
  temperature, reset cause); TMATP 2: 60 bytes `<I4d3d` (rtc, quaternion r i j k, ECI J2000
  position in metres); TMACD 3: 19 bytes; TMSENS 4: 70 bytes `<I3d3f3f3f6b`; TMRAWSENS 5:
  53 bytes `<I6H3h3h3h6h3hB` (the horizon sensor's nadir vector at 1e-4 and its status last);
  TMALL 6: the four above concatenated and the estimated nadir vector `<3f` (177 bytes);
- port 11 RTCSTMGET 2: `<I` UTC unix seconds;
- port 12 ATCMDSET 6 / ATCMDGET 5 (u8 mode), ATCATSET 2 / ATCATGET 1 (`<4d`, 32 bytes);
- an unknown command and a short request: the failure reply `cmd 00`;
- port 10 TMPERSET 7 / TMPERGET 8 (docs/protocol.md "Periodic telemetry", 7 bytes `<BBIB`:
  destination, port, period ms, mask of telemetry commands): TMGEN and TMATP every 250 ms
  to this client's port 20 arrive as their replies would (`cmd 01 data`, from port 10), and
  stop when the period is set to 0.

Checks sizes and plausible values: |position| between --rmin-km and --rmax-km, RTC within
a day of --start. Exit 0 when every check passes; prints one line per check.
"""
import argparse
import math
import os
import struct
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from kiss_peer import Checks, Peer  # noqa: E402  (the m6p package's framing; its ICD cross-checked)

# ICD 4.2.1 (reply data after `command | result`), little-endian.
TMGEN = struct.Struct("<IIIBBbB")          # 16
TMATP = struct.Struct("<I4d3d")            # 60
TMACD = struct.Struct("<IB4B4B3BBBB")      # 19
TMSENS = struct.Struct("<I3d3f3f3f6b")     # 70
RTC = struct.Struct("<I")                  # 4 (ICD 4.2.2)
QUAT = struct.Struct("<4d")                # 32 (ICD 4.2.3, INTERPRETATION.md 5)
PERIODIC = struct.Struct("<BBIB")          # 7 (the twin's TMPERSET/TMPERGET)
assert (TMGEN.size, TMATP.size, TMACD.size, TMSENS.size, RTC.size, QUAT.size) == (16, 60, 19, 70, 4, 32)

PORT_TM, PORT_RTC, PORT_ATC = 10, 11, 12


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--as", dest="me", type=int, default=17)
    ap.add_argument("--fc", type=int, default=3)
    ap.add_argument("--start", type=int, required=True, help="scenario start, UTC unix s")
    ap.add_argument("--rmin-km", type=float, default=6600.0)
    ap.add_argument("--rmax-km", type=float, default=7000.0)
    a = ap.parse_args()
    check = Checks()

    p = Peer(a.connect, a.me)

    def ask(port, cmd, data=b""):
        """Send `cmd | data`; return (result, reply data) or (None, what came)."""
        return p.ask(a.fc, port, cmd, data)

    def rtc_ok(t):
        return abs(t - a.start) <= 86400

    res, d = ask(PORT_TM, 1)
    ok = res == 1 and d is not None and len(d) == TMGEN.size
    check("TMGEN is 2+16 bytes", ok, f"result {res} data {None if d is None else d.hex()}")
    if ok:
        rtc, up, on, mode, state, temp, cause = TMGEN.unpack(d)
        check.agree("TMGEN", TMGEN.unpack(d), p.last_reply)
        check("TMGEN rtc within a day of the start", rtc_ok(rtc), f"rtc {rtc} start {a.start}")
        check("TMGEN uptime and on-time plausible", 0 <= up <= on < 86400, f"uptime {up} on {on}")
        check("TMGEN mode, state, temperature, reset cause plausible",
              mode <= 9 and -40 <= temp <= 85 and cause in (0, 1),
              f"mode {mode} state {state} temp {temp} cause {cause}")

    res, d = ask(PORT_TM, 2)
    ok = res == 1 and d is not None and len(d) == TMATP.size
    check("TMATP is 2+60 bytes", ok, f"result {res} len {None if d is None else len(d)}")
    if ok:
        v = TMATP.unpack(d)
        check.agree("TMATP", v, p.last_reply)
        rtc, q, r = v[0], v[1:5], v[5:8]
        r_km = math.sqrt(sum(x * x for x in r)) / 1000.0
        check("TMATP |position| in LEO (metres, ECI)", a.rmin_km < r_km < a.rmax_km, f"{r_km:.3f} km")
        qn = math.sqrt(sum(x * x for x in q))
        check("TMATP quaternion has unit norm", abs(qn - 1.0) < 1e-9, f"{q}")
        check("TMATP rtc within a day of the start", rtc_ok(rtc), f"{rtc}")

    res, d = ask(PORT_TM, 3)
    ok = res == 1 and d is not None and len(d) == TMACD.size
    check("TMACD is 2+19 bytes", ok, f"result {res} len {None if d is None else len(d)}")
    if ok:
        check.agree("TMACD", TMACD.unpack(d), p.last_reply)
    res, d = ask(PORT_TM, 4)
    ok = res == 1 and d is not None and len(d) == TMSENS.size
    check("TMSENS is 2+70 bytes", ok, f"result {res} len {None if d is None else len(d)}")
    if ok:
        check.agree("TMSENS", TMSENS.unpack(d), p.last_reply)
    res, d = ask(PORT_TM, 5)
    raw = struct.Struct("<I6H3h3h3h6h3hB")
    ok = res == 1 and d is not None and len(d) == raw.size == 53
    check("TMRAWSENS is 2+53 bytes", ok, f"result {res} len {None if d is None else len(d)}")
    if ok:
        v = raw.unpack(d)
        check.agree("TMRAWSENS", v, p.last_reply)
        hz, status = v[22:25], v[25]
        norm = math.sqrt(sum(x * x for x in hz)) * 1e-4
        good = (status == 0 and hz == (0, 0, 0)) or (status in (1, 2) and abs(norm - 1) < 1e-3)
        check("TMRAWSENS horizon: a unit nadir vector with the limb in view, zeros without",
              good, f"status {status} raw {hz}")
    res, d = ask(PORT_TM, 6)
    ok = res == 1 and d is not None and len(d) == 177
    check("TMALL is 2+177 bytes (TMGEN|TMATP|TMACD|TMSENS|nadir)", ok,
          f"result {res} len {None if d is None else len(d)}")
    if ok:
        parts = (TMGEN.unpack(d[:16]) + TMATP.unpack(d[16:76]) + TMACD.unpack(d[76:95])
                 + TMSENS.unpack(d[95:165]) + struct.unpack("<3f", d[165:177]))
        check.agree("TMALL", parts, p.last_reply)
        r = TMATP.unpack(d[16:76])[5:8]
        r_km = math.sqrt(sum(x * x for x in r)) / 1000.0
        check("TMALL's TMATP part is in LEO", a.rmin_km < r_km < a.rmax_km, f"{r_km:.3f} km")
        n = struct.unpack("<3f", d[165:177])
        nn = math.sqrt(sum(x * x for x in n))
        check("TMALL's nadir vector is a unit vector (or zeros before an estimate)",
              nn == 0 or abs(nn - 1) < 1e-5, f"{n}")

    res, d = ask(PORT_RTC, 2)
    ok = res == 1 and d is not None and len(d) == RTC.size
    check("RTCSTMGET is 2+4 bytes", ok, f"result {res} data {None if d is None else d.hex()}")
    if ok:
        (rtc,) = RTC.unpack(d)
        check.agree("RTCSTMGET", RTC.unpack(d), p.last_reply)
        check("RTCSTMGET within a day of the start", rtc_ok(rtc), f"{rtc}")

    res, d = ask(PORT_ATC, 6, bytes([3]))
    check("ATCMDSET nadir (3) succeeds with no data", res == 1 and d == b"", f"result {res} data {d}")
    res, d = ask(PORT_ATC, 5)
    check("ATCMDGET returns nadir (3)", res == 1 and d == bytes([3]), f"result {res} data {d}")
    res, d = ask(PORT_ATC, 6, bytes([42]))
    check("ATCMDSET of an unknown mode fails (cmd 00)", res == 0 and d == b"", f"result {res} data {d}")

    q = (0.5, -0.5, 0.5, 0.5)
    res, d = ask(PORT_ATC, 2, QUAT.pack(*q))
    check("ATCATSET succeeds", res == 1 and d == b"", f"result {res} data {d}")
    res, d = ask(PORT_ATC, 1)
    ok = res == 1 and d is not None and len(d) == QUAT.size
    check("ATCATGET is 2+32 bytes", ok, f"result {res} len {None if d is None else len(d)}")
    if ok:
        check("ATCATGET returns the set quaternion", QUAT.unpack(d) == q, f"{QUAT.unpack(d)}")
        check.agree("ATCATGET", QUAT.unpack(d), p.last_reply)

    res, d = ask(PORT_TM, 0x77)
    check("unknown telemetry command fails (cmd 00)", res == 0 and d == b"", f"result {res} data {d}")
    res, d = ask(PORT_ATC, 2, bytes(16))
    check("ATCATSET with the ICD's 16 bytes fails (cmd 00)", res == 0 and d == b"", f"result {res} data {d}")

    # Periodic telemetry to ourselves, port 20: TMGEN | TMATP every 250 ms.
    res, d = ask(PORT_TM, 7, PERIODIC.pack(a.me, 20, 250, 0x03))
    check("TMPERSET TMGEN|TMATP every 250 ms succeeds", res == 1 and d == b"", f"result {res} {d!r}")
    res, d = ask(PORT_TM, 8)
    check("TMPERGET returns it", res == 1 and d == PERIODIC.pack(a.me, 20, 250, 0x03), f"{d!r}")
    check.agree("TMPERGET", PERIODIC.unpack(d), p.last_reply)
    got = [(h, d) for h, d in p.frames(2.0) if h["dport"] == 20]
    gens = [d for h, d in got if d[:2] == b"\x01\x01" and len(d) == 2 + TMGEN.size]
    atps = [d for h, d in got if d[:2] == b"\x02\x01" and len(d) == 2 + TMATP.size]
    # Unsolicited, so from an ephemeral port of the FC's (never its telemetry port 10, where
    # an answer would be served as a request), the same one for all.
    check("periodic TMGEN and TMATP arrive from one ephemeral port of the FC's, about 8 each in 2 s",
          all(h["src"] == a.fc and h["sport"] >= 32 for h, _ in got)
          and len({h["sport"] for h, _ in got}) == 1
          and 5 <= len(gens) <= 10 and 5 <= len(atps) <= 10 and len(got) == len(gens) + len(atps),
          f"{len(gens)} TMGEN, {len(atps)} TMATP of {len(got)}")
    ups = [TMGEN.unpack(g[2:])[1] for g in gens]
    check("the periodic TMGEN's uptime runs on", ups == sorted(ups) and ups[-1] > ups[0], f"{ups}")
    res, d = ask(PORT_TM, 7, PERIODIC.pack(0, 0, 0, 0))
    check("TMPERSET with period 0 stops it", res == 1, f"result {res}")
    list(p.frames(0.5))
    late = [d for h, d in p.frames(1.0) if h["dport"] == 20]
    check("nothing periodic after the stop", not late, f"{len(late)} packets")
    res, d = ask(PORT_TM, 7, PERIODIC.pack(a.me, 3, 250, 0x01))
    check("TMPERSET to a service port fails (cmd 00)", res == 0 and d == b"", f"result {res} {d!r}")

    check.icd(p)
    sys.exit(1 if check.failures else 0)


if __name__ == "__main__":
    main()
