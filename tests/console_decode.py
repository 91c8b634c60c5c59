#!/usr/bin/env python3
"""An independent client of a node's text console and of its platform port (CSP port 14),
written from docs/protocol.md ("Platform port", "Text console"), not from the twin's code.
The KISS framing is tests/kiss_peer.py's.

As ground node --as (17) on the KISS link --connect, and on the FC's console --console
(TCP, one line in, the answer and the prompt `fc> ` out):

- `help` lists every console command (the node's and the FC's);
- `tm gen` and `tm atp` read what TMGEN and TMATP over CSP read around the same instant;
- the parameter table over CSP: PLIST 4 (`<BB` next id, count, then `id, type, value`
  entries), PINFO 3 (`<BBddd` + name[24] + unit[8]); a parameter set on the console reads
  back over PGET 1; PSET 2 out of range gets `cmd 00` and changes nothing;
- saved (console `param save`), the value survives a reboot through CSP's service port 4;
  a set not saved does not; PDEFAULTS 6 brings the factory value (PINFO's default);
- SELFTEST 7 (`<BB` overall, count, then count x `<Bf` health, reading) has one entry per
  line of the console's `selftest`, with the same health;
- a bad console line gets one line starting `error: `;
- the telemetry store (FC port 10): with `store_period` 1 s and `store_mask` TMGEN, EPS and
  COMM (saved), TMSTOREGET 10 (`<III` from, to, skip; reply `<IB` matching, count, then
  `<IBB` rtc, kind, len + data records) read in chunks gives TMGEN (kind 1, 16 bytes),
  TMEPS (7, 88) and TMCOMM (8) records every second from before and after the reboot (the
  store is non-volatile), matching TMSTOREINFO 9 (`<IIIII`).
Exit 0 when every check passes; one line per check.
"""
import argparse
import os
import socket
import struct
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from kiss_peer import Checks, Peer  # noqa: E402

FC, PLATFORM = 3, 14
PGET, PSET, PINFO, PLIST, PSAVE, PDEFAULTS, SELFTEST = 1, 2, 3, 4, 5, 6, 7
TYPES = {1: "<B", 2: "<H", 3: "<I", 4: "<i", 5: "<f", 6: "<B"}
HEALTH = {0: "ok", 1: "degraded", 2: "FAILED", 3: "off"}
TMGEN = struct.Struct("<IIIBBbB")
TMATP = struct.Struct("<I4d3d")
assert (TMGEN.size, TMATP.size) == (16, 60)


class Console:
    def __init__(self, addr, prompt):
        host, port = addr.rsplit(":", 1)
        self.sock = socket.create_connection((host, int(port)), timeout=5)
        self.prompt = prompt.encode()
        self.banner = self._until_prompt()

    def _until_prompt(self):
        buf = b""
        while not buf.endswith(self.prompt):
            chunk = self.sock.recv(4096)
            if not chunk:
                raise RuntimeError("console closed")
            buf += chunk
        return buf[: -len(self.prompt)].decode().replace("\r\n", "\n")

    def run(self, line):
        self.sock.sendall(line.encode() + b"\r\n")
        return self._until_prompt()


def fields(text):
    out = {}
    for line in text.splitlines():
        k, _, v = line.partition(" ")
        out[k] = v
    return out


def value(t, b):
    return struct.unpack(TYPES[t], b)[0]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--as", dest="me", type=int, default=17)
    ap.add_argument("--console", required=True)
    a = ap.parse_args()
    check = Checks()
    peer = Peer(a.connect, a.me)
    con = Console(a.console, "fc> ")
    check("banner names the FC", "FC console" in con.banner, con.banner.strip())

    names = {l.split()[0] for l in con.run("help").splitlines() if l.strip()}
    want = {"help", "uptime", "counters", "log", "param", "selftest", "reboot", "tm", "mode"}
    check("help lists every command", want <= names, f"{sorted(names)}")

    # Telemetry on the console and over CSP around the same instant.
    r0, d0 = peer.ask(FC, 10, 1)
    text = con.run("tm gen")
    r1, d1 = peer.ask(FC, 10, 1)
    g0, g1, f = TMGEN.unpack(d0), TMGEN.unpack(d1), fields(text)
    rtc = int(f["rtc_timestamp"].split()[0])
    check("tm gen: rtc between two TMGEN", g0[0] <= rtc <= g1[0], f"{g0[0]} {rtc} {g1[0]}")
    for i, k in [(3, "current_mode"), (4, "current_state"), (6, "reset_cause")]:
        check(f"tm gen: {k} as TMGEN", int(f[k].split()[0]) in (g0[i], g1[i]), f"{f[k]} {g0[i]}")
    r0, d0 = peer.ask(FC, 10, 2)
    f = fields(con.run("tm atp"))
    a0 = TMATP.unpack(d0)
    # One `name value unit` line per field, arrays by element: r_eci_m[0] .. r_eci_m[2] in m.
    r_km = [float(f[f"r_eci_m[{i}]"].split()[0]) / 1000 for i in range(3)]
    dist = sum((r_km[i] - a0[5 + i] / 1000) ** 2 for i in range(3)) ** 0.5
    check("tm atp: position as TMATP (within 1 s of flight)", dist < 8.0, f"{dist:.3f} km")

    # The table over CSP.
    table, first = {}, 0
    while first != 0xFF:
        r, d = peer.ask(FC, PLATFORM, PLIST, bytes([first]))
        nxt, count, at = d[0], d[1], 2
        for _ in range(count):
            pid, t = d[at], d[at + 1]
            size = struct.calcsize(TYPES[t])
            table[pid] = (t, value(t, d[at + 2 : at + 2 + size]))
            at += 2 + size
        first = nxt
    info = {}
    for pid in table:
        r, d = peer.ask(FC, PLATFORM, PINFO, bytes([pid]))
        _, t, lo, hi, default = struct.unpack("<BBddd", d[:26])
        name = d[26:50].split(b"\0")[0].decode()
        info[name] = (pid, t, lo, hi, default)
    check("PLIST and PINFO agree", len(info) == len(table) >= 10, f"{sorted(info)}")
    pid, t, lo, hi, default = info["bdot_gain"]

    def pget(pid):
        r, d = peer.ask(FC, PLATFORM, PGET, bytes([pid]))
        return value(d[1], d[2:]) if r == 1 else None

    con.run("param set bdot_gain 0.125")
    check("a console set reads back over CSP", pget(pid) == 0.125, str(pget(pid)))
    r, d = peer.ask(FC, PLATFORM, PSET, bytes([pid]) + struct.pack("<f", hi * 2))
    check("PSET out of range refused", r == 0 and d == b"" and pget(pid) == 0.125, f"{r}")
    con.run("param set store_period 1")
    con.run("param set store_mask 193")  # 0xC1: TMGEN, the EPS, the COMM
    check("console save", con.run("param save").strip() == "saved")
    time.sleep(2.5)
    sun = info["use_sun"][0]
    con.run("param set use_sun off")
    check("use_sun off before the reboot", pget(sun) == 0)

    # Reboot over CSP (service port 4, libcsp's magic word).
    peer.request(FC, 4, struct.pack(">I", 0x80078007), timeout=0.5)
    time.sleep(0.5)
    r, d = peer.ask(FC, 10, 1)
    g = TMGEN.unpack(d)
    check("the FC rebooted (software reset, uptime from zero)", g[6] == 1 and g[1] <= 2, f"{g}")
    check("the saved value survived the reboot", pget(pid) == 0.125, str(pget(pid)))
    check("the unsaved set did not", pget(sun) == 1, str(pget(sun)))

    # Self-test over CSP and on the console.
    r, d = peer.ask(FC, PLATFORM, SELFTEST)
    overall, count = d[0], d[1]
    entries = [struct.unpack("<Bf", d[2 + 5 * i : 7 + 5 * i]) for i in range(count)]
    lines = con.run("selftest").splitlines()
    check("selftest: one entry per console line", len(lines) == 1 + count, f"{count} {lines}")
    same = all(HEALTH[h] == l.split()[1] for (h, _), l in zip(entries, lines[1:]))
    check("selftest: the same health", same and lines[0] == "overall " + HEALTH[overall], lines[0])

    # The FC's state machine: thresholds above the battery's charge make it SAFE at its next
    # tick (TMGEN current_state 1); the defaults (15 % / 30 %) make it NOMINAL again.
    peer.ask(FC, PLATFORM, PSET, bytes([info["safe_exit_soc"][0], 100]))
    peer.ask(FC, PLATFORM, PSET, bytes([info["safe_enter_soc"][0], 99]))
    time.sleep(0.5)
    r, d = peer.ask(FC, 10, 1)
    check("SAFE when the battery is below safe_enter_soc", TMGEN.unpack(d)[4] == 1, f"{TMGEN.unpack(d)}")
    r, d = peer.ask(FC, PLATFORM, PDEFAULTS)
    check("PDEFAULTS restores the factory value", r == 1 and abs(pget(pid) - default) < 1e-6,
          f"{pget(pid)} {default}")
    time.sleep(0.5)
    r, d = peer.ask(FC, 10, 1)
    check("NOMINAL again with the default thresholds", TMGEN.unpack(d)[4] == 0, f"{TMGEN.unpack(d)}")
    time.sleep(2.2)
    r, d = peer.ask(FC, 10, 9)
    n, nbytes, oldest, newest, over = struct.unpack("<IIIII", d)
    records, skip = [], 0
    while True:
        r, d = peer.ask(FC, 10, 10, struct.pack("<III", oldest, newest, skip))
        matching, count = struct.unpack("<IB", d[:5])
        at = 5
        for _ in range(count):
            rtc, kind, ln = struct.unpack("<IBB", d[at : at + 6])
            records.append((rtc, kind, d[at + 6 : at + 6 + ln]))
            at += 6 + ln
        skip += count
        if count == 0 or skip >= matching:
            break
    check("store: every record read in chunks", len(records) == n == matching, f"{len(records)} {n}")
    kinds = {k: [r for r in records if r[1] == k] for k in (1, 7, 8)}
    check("store: TMGEN, TMEPS and TMCOMM kept", all(len(v) >= 3 for v in kinds.values()),
          str({k: len(v) for k, v in kinds.items()}))
    sizes = {len(r[2]) for r in kinds[1]} | {len(r[2]) + 1000 for r in kinds[7]}
    check("store: record sizes", sizes == {16, 1088}, str(sizes))
    rtcs = [r[0] for r in records]
    check("store: in time order", rtcs == sorted(rtcs), str(rtcs))
    ups = [TMGEN.unpack(r[2])[1] for r in kinds[1]]
    check("store: records from before and after the reboot",
          any(b < a for a, b in zip(ups, ups[1:])), str(ups))
    err = con.run("param set nothing 1")
    check("a bad line is one error line", err.startswith("error: ") and err.count("\n") == 1, err)
    check.icd(peer)
    sys.exit(1 if check.failures else 0)


if __name__ == "__main__":
    main()
