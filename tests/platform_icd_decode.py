#!/usr/bin/env python3
"""An independent decoder of the platform nodes' port 10 (EPS, ECU, COMM1, COMM2), written
from the tables in docs/protocol.md sections "EPS (CSP 4, port 10 ...)", "COMM (CSP 1 and 2,
port 10 ...)" and "ECU (CSP 5, port 10 ...)" (and docs/platform.md for plausible ranges),
not from the twin's code.

It joins a running twin over KISS/TCP as a ground node (default 16; the framing is
tests/kiss_peer.py's, itself written from libcsp 1.4). Every request is `cmd u8 | data`,
every reply `cmd u8 | result u8 (1 ok / 0 fail) | data`, little-endian, IEEE-754 binary32;
every malformed request gets `cmd 00` with no data. It asks:

- EPS (node 4): TMEPS 1 (88 bytes), CHGET 2 (`on u16, shed u16`), CHSET 3 (`channel u8,
  on u8`) of payload 15's channel off then on (and back as found), THRGET 4 (4 x u8 % SOC),
  THRSET 5 with shed >= restore (fails) and with the values read (succeeds), an unknown
  command and a 1-byte CHSET (fail);
- ECU (node 5): TMECU 1 (42 bytes), FIRE 3 while SAFE (fails), ARM 2 (`warmup_left_ms
  u32`), FIRE of 0 ms (fails), ARM with data (fails), SAFE 4 (no data), TMECU again (SAFE,
  heater off, `refused` counted the refusals);
- COMM (nodes 1 and 2): TMCOMM 1 (58 bytes; role and radio_active), BEACONGET 3 (`period_s
  u16`, 60 by default), BEACONSET 2 of 9 s (fails: 0 or 10..=3600) and of 120 s (succeeds;
  BEACONGET then says 120), BEACON 4 (171 bytes: once the truth is valid, position in LEO,
  unit quaternion and sun vector, sun_visible_pct <= 100).

Exit 0 when every check passes; prints one PASS/FAIL line per check.
"""
import argparse
import math
import os
import struct
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from kiss_peer import Checks, Peer  # noqa: E402  (KISS framing and CSP header, from the spec)

PORT = 10

# EPS (docs/protocol.md "EPS"): reply data after `cmd | result`.
EPS_TMEPS, EPS_CHGET, EPS_CHSET, EPS_THRGET, EPS_THRSET = 1, 2, 3, 4, 5
# TmEps: V, A, SOC, Wh, array W, load W | panel count u8 | 8 x panel W | on u16, shed u16 |
# 9 x channel mA u16 | protection u8 | array Wh, load Wh.
TMEPS = struct.Struct("<6fB8fHH9HBff")        # 88
CHANNELS = struct.Struct("<HH")               # 4: on, shed
THRESHOLDS = struct.Struct("<4B")             # 4: payload shed, restore, platform shed, restore
N_CHANNELS = 9                                # 0 COMM1, 1 COMM2, 2 ECU, 3 PC, 4-7 PL12-15, 8 S-band
CH_COMM1, CH_PL15 = 0, 4 + (15 - 12)

# ECU (docs/protocol.md "ECU").
ECU_TMECU, ECU_ARM, ECU_FIRE, ECU_SAFE = 1, 2, 3, 4
# state, heater | warmup_left_ms, burn_left_ms | propellant kg, pressure kPa, thrust N, mass kg,
# total impulse N s | burns, last_burn_ms, refused.
TMECU = struct.Struct("<BBII5fIII")           # 42
U32 = struct.Struct("<I")
SAFE, WARMING, ARMED, FIRING = 0, 1, 2, 3

# COMM (docs/protocol.md "COMM").
COMM_TMCOMM, COMM_BEACONSET, COMM_BEACONGET, COMM_BEACON = 1, 2, 3, 4
# role, radio_active, in_contact, station | elevation, azimuth, range, rssi, snr | uptime,
# beacons_sent | beacon_period_s u16 | beacon_air_ms, rx, tx, forwarded, drops, refused.
TMCOMM = struct.Struct("<4B5fIIHIIIIII")      # 58
U16 = struct.Struct("<H")
# The beacon, field by field at the table's offsets.
BEACON_SIZE = 171
B_HEAD = (0, struct.Struct("<IIIBI"))         # seq, utc_s, uptime_s, flags, truth_utc_s
B_R = (17, struct.Struct("<3f"))              # r_eci_km
B_V = (29, struct.Struct("<3f"))              # v_eci_km_s
B_LLA = (41, struct.Struct("<3f"))            # lat_deg, lon_deg, alt_km
B_Q = (53, struct.Struct("<4f"))              # q_eci_from_body, scalar first
B_W = (69, struct.Struct("<3f"))              # w_body_deg_s
B_SUN = (81, struct.Struct("<3f"))            # sun_body_unit
B_SUNPCT = (93, struct.Struct("<B"))          # sun_visible_pct
B_B = (94, struct.Struct("<3f"))              # b_body_nt
B_WHEELS = (106, struct.Struct("<4f"))        # wheel_speed_rpm
B_MTQ = (122, struct.Struct("<3f"))           # mtq_dipole_am2
B_LINK = (134, struct.Struct("<B4f"))         # station, elevation, azimuth, range, rssi
B_COUNTERS = (151, struct.Struct("<4I"))      # rx, tx, forwarded, drops
B_TAIL = (167, struct.Struct("<HH"))          # reboots, beacon_period_s
F_TRUTH, F_CONTACT, F_SECONDARY = 0x01, 0x02, 0x04

assert (TMEPS.size, CHANNELS.size, THRESHOLDS.size, TMECU.size, TMCOMM.size) == (88, 4, 4, 42, 58)
assert B_TAIL[0] + B_TAIL[1].size == BEACON_SIZE


def field(data, spec):
    off, st = spec
    return st.unpack_from(data, off)


def hx(mask):
    return None if mask is None else f"{mask:#05x}"


def norm(v):
    return math.sqrt(sum(x * x for x in v))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--as", dest="me", type=int, default=17)
    ap.add_argument("--eps", type=int, default=4)
    ap.add_argument("--ecu", type=int, default=5)
    ap.add_argument("--comm", default="1,2")
    ap.add_argument("--truth-wait-s", type=float, default=8.0,
                    help="how long to ask BEACON again until its truth is valid")
    a = ap.parse_args()
    check = Checks()

    p = Peer(a.connect, a.me)

    def ask(node, cmd, data=b""):
        """Send `cmd | data` to port 10; return (result, reply data) or (None, raw reply)."""
        return p.ask(node, PORT, cmd, data)

    def failed(name, node, cmd, data=b""):
        res, d = ask(node, cmd, data)
        check(name + f" (`{cmd:02x} 00`)", res == 0 and d == b"", f"result {res} data {d}")

    def sized(name, res, d, size):
        ok = res == 1 and d is not None and len(d) == size
        check(f"{name} is 2+{size} bytes", ok, f"result {res} len {None if d is None else len(d)}")
        return ok

    # ---- EPS ----
    eps = a.eps
    res, d = ask(eps, EPS_TMEPS)
    tm_on = None
    if sized("TMEPS", res, d, TMEPS.size):
        v = TMEPS.unpack(d)
        check.agree("TMEPS", v, p.last_reply)
        volt, amp, soc, wh, array_w, load_w, panels = v[0:7]
        panel_w = v[7:15]
        on, shed = v[15], v[16]
        ch_ma = v[17:26]
        prot, array_wh, load_wh = v[26], v[27], v[28]
        tm_on = on
        check("TMEPS state of charge in 0..1", 0.0 <= soc <= 1.0, f"soc {soc:.4f}")
        check("TMEPS battery voltage within 6.00-8.36 V", 6.0 <= volt <= 8.36, f"{volt:.3f} V")
        check("TMEPS stored energy, powers and energies not negative",
              wh >= 0 and array_w >= 0 and load_w > 0 and array_wh >= 0 and load_wh >= 0
              and all(w >= 0 for w in panel_w),
              f"{wh:.2f} Wh, array {array_w:.2f} W, load {load_w:.2f} W, since boot "
              f"{array_wh:.4f}/{load_wh:.4f} Wh, current {amp:.3f} A")
        check("TMEPS panel count <= 8, unused panels at 0 W",
              panels <= 8 and all(w == 0 for w in panel_w[panels:]),
              f"{panels} panels {['%.2f' % w for w in panel_w]}")
        check("TMEPS channel masks use bits 0-8 only, COMM1 (bit 0) on, none on and shed",
              on >> N_CHANNELS == 0 and shed >> N_CHANNELS == 0 and on & (1 << CH_COMM1)
              and on & shed == 0, f"on {on:#05x} shed {shed:#05x}")
        check("TMEPS channels off draw no current, channels on draw some",
              all((c == 0) == (not on >> i & 1) for i, c in enumerate(ch_ma)),
              f"mA {list(ch_ma)} on {on:#05x}")
        check("TMEPS protection uses bits 0-2, battery not empty", prot >> 3 == 0 and not prot & 4,
              f"{prot:#04x}")

    res, d = ask(eps, EPS_CHGET)
    on0 = None
    if sized("CHGET", res, d, CHANNELS.size):
        on0, shed0 = CHANNELS.unpack(d)
        check("CHGET's on mask is TMEPS's", on0 == tm_on, f"on {on0:#05x} TMEPS {hx(tm_on)}")

    res, d = ask(eps, EPS_CHSET, bytes([CH_PL15, 0]))
    if sized("CHSET payload 15 off", res, d, CHANNELS.size):
        on, shed = CHANNELS.unpack(d)
        check("CHSET off: payload 15's bit clear, the others as before",
              on0 is not None and on == on0 & ~(1 << CH_PL15), f"on {on:#05x} before {hx(on0)}")
    res, d = ask(eps, EPS_CHSET, bytes([CH_PL15, 1]))
    if sized("CHSET payload 15 on", res, d, CHANNELS.size):
        on, shed = CHANNELS.unpack(d)
        check("CHSET on: payload 15's bit set, the others as before",
              on0 is not None and on == on0 | (1 << CH_PL15), f"on {on:#05x} before {hx(on0)}")
    if on0 is not None:
        was = on0 >> CH_PL15 & 1
        res, d = ask(eps, EPS_CHSET, bytes([CH_PL15, was]))
        check("CHSET back as found restores CHGET's mask",
              res == 1 and d is not None and len(d) == 4 and CHANNELS.unpack(d)[0] == on0,
              f"result {res} data {None if d is None else d.hex()}")
    res, d = ask(eps, EPS_CHGET)
    check("CHGET after the switching is as at first",
          res == 1 and d is not None and len(d) == 4 and CHANNELS.unpack(d)[0] == on0,
          f"result {res} data {None if d is None else d.hex()}")

    res, d = ask(eps, EPS_THRGET)
    thr = None
    if sized("THRGET", res, d, THRESHOLDS.size):
        thr = THRESHOLDS.unpack(d)
        ps, pr, fs, fr = thr
        check("THRGET shed < restore <= 100 for both groups", ps < pr <= 100 and fs < fr <= 100,
              f"payload {ps}/{pr} platform {fs}/{fr} %")
    if thr is not None:
        ps, pr, fs, fr = thr
        failed("THRSET with payload shed >= restore fails", eps, EPS_THRSET, bytes([pr, ps, fs, fr]))
        failed("THRSET with platform shed == restore fails", eps, EPS_THRSET, bytes([ps, pr, fr, fr]))
        failed("THRSET with restore > 100 fails", eps, EPS_THRSET, bytes([ps, 101, fs, fr]))
        res, d = ask(eps, EPS_THRGET)
        check("THRGET unchanged by the refused THRSETs", res == 1 and d == bytes(thr),
              f"result {res} data {d}")
        res, d = ask(eps, EPS_THRSET, bytes(thr))
        check("THRSET of the values read succeeds with no data", res == 1 and d == b"",
              f"result {res} data {d}")
    failed("EPS unknown command fails", eps, 0x77)
    failed("CHSET with 1 byte fails", eps, EPS_CHSET, bytes([CH_PL15]))
    failed("CHSET with 3 bytes fails", eps, EPS_CHSET, bytes([CH_PL15, 1, 0]))
    failed("CHSET of channel 9 fails", eps, EPS_CHSET, bytes([9, 1]))
    failed("CHSET with on = 2 fails", eps, EPS_CHSET, bytes([CH_PL15, 2]))
    failed("TMEPS with data fails", eps, EPS_TMEPS, b"\x00")

    # ---- ECU ----
    ecu = a.ecu
    res, d = ask(ecu, ECU_TMECU)
    refused0 = None
    if sized("TMECU", res, d, TMECU.size):
        (state, heater, warm_ms, burn_ms, prop_kg, p_kpa, thrust_n, mass_kg, imp_ns,
         burns, last_ms, refused0) = TMECU.unpack(d)
        check.agree("TMECU", TMECU.unpack(d), p.last_reply)
        check("TMECU state SAFE (0), heater off, nothing burning",
              state == SAFE and heater == 0 and burn_ms == 0, f"state {state} heater {heater} "
              f"warm-up {warm_ms} ms burn {burn_ms} ms")
        check("TMECU propellant > 0 and mass = dry + propellant > propellant",
              0 < prop_kg < mass_kg, f"{prop_kg:.4f} kg of {mass_kg:.3f} kg")
        check("TMECU blow-down pressure plausible (550-2200 kPa)", 550 <= p_kpa <= 2200,
              f"{p_kpa:.1f} kPa")
        check("TMECU next burn's thrust plausible (0-1 N)", 0 < thrust_n < 1, f"{thrust_n:.4f} N")
        check("TMECU no burn yet", burns == 0 and last_ms == 0 and imp_ns == 0,
              f"burns {burns} last {last_ms} ms impulse {imp_ns}")
    failed("FIRE while SAFE fails", ecu, ECU_FIRE, U32.pack(1000))
    res, d = ask(ecu, ECU_ARM)
    ok = res == 1 and d is not None and len(d) == U32.size
    check("ARM is 02 01 + 4 bytes", ok, f"result {res} data {d}")
    if ok:
        (left,) = U32.unpack(d)
        check("ARM warm-up left about 60 s", 55_000 <= left <= 60_000, f"{left} ms")
    res, d = ask(ecu, ECU_TMECU)
    if sized("TMECU after ARM", res, d, TMECU.size):
        state, heater, warm_ms = TMECU.unpack(d)[0:3]
        check("TMECU after ARM: WARMING, heater on, warm-up counting down",
              state == WARMING and heater == 1 and 0 < warm_ms <= 60_000,
              f"state {state} heater {heater} warm-up {warm_ms} ms")
    failed("FIRE of 0 ms fails", ecu, ECU_FIRE, U32.pack(0))
    failed("FIRE while WARMING fails", ecu, ECU_FIRE, U32.pack(1000))
    failed("FIRE with 2 bytes fails", ecu, ECU_FIRE, bytes([0xE8, 0x03]))
    failed("ARM with data fails", ecu, ECU_ARM, b"\x01")
    failed("SAFE with data fails", ecu, ECU_SAFE, b"\x00")
    failed("ECU unknown command fails", ecu, 0x77)
    res, d = ask(ecu, ECU_SAFE)
    check("SAFE is 04 01 with no data", res == 1 and d == b"", f"result {res} data {d}")
    res, d = ask(ecu, ECU_TMECU)
    if sized("TMECU after SAFE", res, d, TMECU.size):
        v = TMECU.unpack(d)
        check("TMECU after SAFE: SAFE, heater off", v[0] == SAFE and v[1] == 0,
              f"state {v[0]} heater {v[1]}")
        check("TMECU refused counted the 7 refusals", refused0 is not None and v[11] == refused0 + 7,
              f"refused {v[11]} before {refused0}")

    # ---- COMM1 and COMM2 ----
    for node in [int(x) for x in a.comm.split(",")]:
        role_want, active_want = (1, 1) if node == 1 else (2, 0)
        n = f"COMM{node}"
        res, d = ask(node, COMM_TMCOMM)
        refused0 = None
        if sized(f"{n} TMCOMM", res, d, TMCOMM.size):
            v = TMCOMM.unpack(d)
            check.agree(f"{n} TMCOMM", v, p.last_reply)
            role, active, contact, station = v[0:4]
            el, az, rng, rssi, snr = v[4:9]
            uptime, sent, period, air_ms, rx, tx, fwd, drops, refused = v[9:]
            refused0 = refused
            check(f"{n} TMCOMM role {role_want}, radio_active {active_want}",
                  role == role_want and active == active_want, f"role {role} active {active}")
            check(f"{n} TMCOMM in_contact 0/1, station index or 0xFF, beacon period 60 s",
                  contact in (0, 1) and (station == 0xFF or station < 16) and period == 60,
                  f"contact {contact} station {station} period {period}")
            check(f"{n} TMCOMM link figures plausible",
                  station == 0xFF or (-90 <= el <= 90 and 0 <= az <= 360 and 0 < rng < 50_000
                                      and -200 < rssi < 0 and snr >= 0),
                  f"el {el:.2f} az {az:.2f} range {rng:.1f} km rssi {rssi:.1f} dBm snr {snr:.1f} dB")
            check(f"{n} TMCOMM uptime < 60 s, no beacon yet, counters sane",
                  uptime < 60 and sent == 0 and air_ms == 0 and rx >= 1 and drops == 0,
                  f"uptime {uptime} sent {sent} air {air_ms} ms rx {rx} tx {tx} fwd {fwd} "
                  f"drops {drops} refused {refused}")
        res, d = ask(node, COMM_BEACONGET)
        check(f"{n} BEACONGET is 2+2 bytes, 60 s", res == 1 and d is not None and len(d) == 2
              and U16.unpack(d)[0] == 60, f"result {res} data {d}")
        failed(f"{n} BEACONSET 9 s fails", node, COMM_BEACONSET, U16.pack(9))
        failed(f"{n} BEACONSET 3601 s fails", node, COMM_BEACONSET, U16.pack(3601))
        failed(f"{n} BEACONSET with 1 byte fails", node, COMM_BEACONSET, b"\x78")
        failed(f"{n} unknown command fails", node, 0x77)
        res, d = ask(node, COMM_BEACONSET, U16.pack(120))
        check(f"{n} BEACONSET 120 s succeeds with no data", res == 1 and d == b"",
              f"result {res} data {d}")
        res, d = ask(node, COMM_BEACONGET)
        check(f"{n} BEACONGET then says 120 s", res == 1 and d == U16.pack(120),
              f"result {res} data {d}")
        res, d = ask(node, COMM_TMCOMM)
        check(f"{n} TMCOMM refused counted the 4 refusals",
              res == 1 and d is not None and len(d) == TMCOMM.size
              and refused0 is not None and TMCOMM.unpack(d)[-1] == refused0 + 4,
              f"result {res} refused {None if d is None or len(d) != 58 else TMCOMM.unpack(d)[-1]} "
              f"before {refused0}")

        deadline = time.monotonic() + a.truth_wait_s
        while True:
            res, d = ask(node, COMM_BEACON)
            ok = res == 1 and d is not None and len(d) == BEACON_SIZE
            if not ok or field(d, B_HEAD)[3] & F_TRUTH or time.monotonic() > deadline:
                break
            time.sleep(0.5)
        if not sized(f"{n} BEACON", res, d, BEACON_SIZE):
            continue
        seq, utc, up, flags, truth_utc = field(d, B_HEAD)
        beacon = [x for f in (B_HEAD, B_R, B_V, B_LLA, B_Q, B_W, B_SUN, B_SUNPCT, B_B, B_WHEELS,
                              B_MTQ, B_LINK, B_COUNTERS, B_TAIL) for x in field(d, f)]
        check.agree(f"{n} BEACON", beacon, p.last_reply)
        check(f"{n} BEACON truth valid (flags bit 0)", flags & F_TRUTH, f"flags {flags:#04x}")
        check(f"{n} BEACON seq 0 (none sent), flags use bits 0-2, secondary bit "
              f"{'set' if node != 1 else 'clear'}",
              seq == 0 and flags >> 3 == 0 and bool(flags & F_SECONDARY) == (node != 1),
              f"seq {seq} flags {flags:#04x}")
        check(f"{n} BEACON truth no later than the COMM clock", 0 < truth_utc <= utc,
              f"utc {utc} truth {truth_utc} uptime {up}")
        r = field(d, B_R)
        check(f"{n} BEACON |r_eci_km| in 6500-7100 km", 6500 < norm(r) < 7100, f"{norm(r):.3f} km")
        vv = field(d, B_V)
        check(f"{n} BEACON |v_eci_km_s| in 7.0-8.0 km/s", 7.0 < norm(vv) < 8.0, f"{norm(vv):.4f}")
        lat, lon, alt = field(d, B_LLA)
        check(f"{n} BEACON sub-satellite point plausible",
              -90 <= lat <= 90 and -180 <= lon <= 360 and 100 < alt < 800,
              f"lat {lat:.3f} lon {lon:.3f} alt {alt:.2f} km")
        q = field(d, B_Q)
        check(f"{n} BEACON quaternion norm ~1", abs(norm(q) - 1) < 1e-4, f"{q}")
        s = field(d, B_SUN)
        check(f"{n} BEACON sun_body_unit norm ~1", abs(norm(s) - 1) < 1e-4, f"{s}")
        (pct,) = field(d, B_SUNPCT)
        check(f"{n} BEACON sun_visible_pct <= 100", pct <= 100, f"{pct} %")
        b = field(d, B_B)
        check(f"{n} BEACON |b_body_nt| of LEO (15-70 uT)", 15_000 < norm(b) < 70_000,
              f"{norm(b):.0f} nT")
        check(f"{n} BEACON rates, wheels and dipoles finite",
              all(math.isfinite(x) for x in field(d, B_W) + field(d, B_WHEELS) + field(d, B_MTQ)),
              f"w {field(d, B_W)}")
        station = field(d, B_LINK)[0]
        rx, tx, fwd, drops = field(d, B_COUNTERS)
        reboots, period = field(d, B_TAIL)
        check(f"{n} BEACON station, counters, reboots, period 120 s",
              (station == 0xFF or station < 16) and rx >= 1 and drops == 0 and reboots == 0
              and period == 120,
              f"station {station} rx {rx} tx {tx} fwd {fwd} drops {drops} reboots {reboots} "
              f"period {period}")

    check.icd(p)
    sys.exit(1 if check.failures else 0)


if __name__ == "__main__":
    main()
