#!/usr/bin/env bash
# Round trips of an outside libcsp 1.4 program to the PC through the twin, over the KISS
# pty and over the ZMQ hub: what the twin adds to the simulated bus time of the exchange.
#
#   tools/sil/latency.sh [N]        (N exchanges per link, default 1000)
#
# For each link: the release twin runs in real time with the link for address 10 and
# records; tests/libcsp's csp_client sends N requests to the PC (TMPC, port 12, command 1,
# 91-byte reply) one after the other and reports the median round trip it measured; the
# recording gives, for each exchange, the simulated time from the request entering the twin
# (the last chunk of it the link read) to the reply leaving it (its `out` frame): the bus time of the
# exchange (CAN frames both ways, the PC's handling), which the twin reproduces exactly.
# Measured minus simulated is what the twin (its scheduling, the pty or ZMQ transport) and
# libcsp's own threads add. Medians of the N exchanges, from one run per link.
set -euo pipefail
cd "$(dirname "$0")/../.."
n=${1:-1000}
out=target/sil-latency
mkdir -p "$out"
cargo build --release -q -p m6p-twin
tests/libcsp/build.sh "$out/libcsp" >/dev/null
twin=target/release/m6p-twin
client=$out/libcsp/bin/csp_client
secs=$(( n * 4 / 1000 + 8 ))

measure() { # name link-args client-iface-args
  local name=$1 link=$2 iface=$3 rec=$out/$1.mcap
  rm -f "$rec" # this script's own output from a run before (the twin never replaces one)
  # shellcheck disable=SC2086
  $twin run --duration "${secs}s" $link --kiss-addr 10 --record "$rec" >"$out/$name.twin.log" 2>&1 &
  local pid=$!
  sleep 1
  # shellcheck disable=SC2086
  $client $iface --addr 10 --settle 500 repeat "$n" icd 6 12 01 91 2>/dev/null >"$out/$name.client.txt" || true
  wait "$pid" || true   # the default scenario's expectations need not hold here
  local ch
  ch=$($twin inspect "$rec" | awk '/\/kiss\/.*\/in /{print $1}' | sed 's#/in$##')
  $twin inspect "$rec" --csv "$ch/in" >"$out/$name.in.csv" 2>/dev/null
  $twin inspect "$rec" --csv "$ch/out" >"$out/$name.out.csv" 2>/dev/null
  python3 - "$name" "$out/$name.client.txt" "$out/$name.in.csv" "$out/$name.out.csv" <<'PY'
import csv, re, statistics, sys
name, client, fin, fout = sys.argv[1:]
text = open(client).read()
m = re.search(r"n=(\d+) passed=(\d+) min_us=(\d+) median_us=(\d+)", text)
if not m:
    sys.exit(f"{name}: no result from csp_client:\n{text}")
n, passed, _, median_us = map(int, m.groups())
ins = [int(r["t_ns"]) for r in csv.DictReader(open(fin)) if int(r["len"]) > 0]
outs = [int(r["t_ns"]) for r in csv.DictReader(open(fout))]
# Each reply follows its request, the only traffic on the link: the request entered the
# twin with the last chunk read before the reply (libcsp's KISS driver writes a frame one
# byte at a time, so a request may come in several chunks).
sim, i = [], 0
for o in outs:
    while i + 1 < len(ins) and ins[i + 1] <= o:
        i += 1
    if i < len(ins) and ins[i] <= o:
        sim.append(o - ins[i])
sim_us = statistics.median(sim) / 1000
print(f"{name}: {passed}/{n} exchanges; measured round trip median {median_us} us; "
      f"simulated exchange median {sim_us:.0f} us ({len(sim)} paired); "
      f"the twin and its transport add {median_us - sim_us:.0f} us")
PY
}

measure pty "--kiss-pty $PWD/$out/tty" "--kiss $PWD/$out/tty"
measure zmq-hub "--zmq-hub 127.0.0.99" "--zmq 127.0.0.99"
