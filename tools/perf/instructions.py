#!/usr/bin/env python3
"""The twin's cost in instructions, counted by valgrind's cachegrind (`--cache-sim=no`):
deterministic, the same on any x86-64 machine, so that two builds compare on a loaded one.

What it counts, each in a process of its own (every thread counted):
- one simulated hour (`--duration`) of a scenario (`--scenario`, the full day by default)
  three ways, as `m6p-twin bench` runs them: `plain` (the whole network, no recording),
  `recorded` (the same, recorded to MCAP), `adcs_floor` (the FC's core alone);
- CSP request-reply round trips over one timed CAN bus, 64-byte payload
  (`bench-run --variant round_trips`), counted at two counts so that start-up cancels;
- a shipped campaign's runs (`--campaign`), at two run counts likewise.

It prints one JSON object: the counts, the CAN frames and ground packets each run carried
(from the run itself), and the figures derived from them (instructions per CAN frame of the
network, the recorder's share of the plain run, instructions per round trip and per
campaign run), so that a dashboard can plot them build after build. `by_area` splits the
network's instructions per CAN frame and the round trip's by where they are spent (the
functions' own instructions, grouped by name: AREAS below), the plain run's minus the floor's.

    python3 tools/perf/instructions.py target/release/m6p-twin > perf.json
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SUMMARY = re.compile(r"^summary:\s+(\d+)", re.MULTILINE)

# Where a function's own instructions go, by its (demangled) name; the first match decides.
# "async runtime" is tokio's scheduler, timers and channels with the futures and clock reads
# they drive; "memory" is allocation, copies and drops; the rest are the twin's crates.
AREAS = [
    ("async runtime", re.compile(r"tokio|PollFn|future::future::Future>::poll|Timespec"
                                 r"|std::time::Instant|clock_gettime|std::thread|std::sync"
                                 r"|parking|futex|syscall|epoll|[Ww]aker")),
    ("bus", re.compile(r"^<?m6p_bus")),
    ("memory", re.compile(r"memcpy|memmove|memset|malloc|free|realloc|calloc|alloc::|__rust_"
                          r"|__rdl_|RawVec|drop_in_place")),
    ("csp", re.compile(r"^<?(m6p_csp|crc32c)")),
    ("nodes", re.compile(r"^<?m6p_nodes")),
    ("run loop and observers", re.compile(r"^<?m6p_(twin|platform|icd|links)")),
]


def parse_duration_ns(text: str) -> int:
    units = {"ms": 10**6, "s": 10**9, "min": 60 * 10**9, "h": 3600 * 10**9}
    m = re.fullmatch(r"(\d+)(ms|s|min|h)", text.strip())
    if not m:
        raise SystemExit(f"--duration {text!r}: a whole number of ms, s, min or h")
    return int(m.group(1)) * units[m.group(2)]


def cachegrind(argv: list[str], work: Path, tag: str) -> tuple[int, str]:
    """Instructions of `argv` and everything it starts (threads and child processes), and
    its standard output."""
    out = work / f"{tag}.%p.cg"
    cmd = ["valgrind", "--tool=cachegrind", "--cache-sim=no", "--trace-children=yes",
           f"--cachegrind-out-file={out}", *argv]
    p = subprocess.run(cmd, check=False, capture_output=True, text=True, cwd=ROOT)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({p.returncode}):\n{p.stderr[-3000:]}")
    total = 0
    for f in work.glob(f"{tag}.*.cg"):
        m = SUMMARY.search(f.read_text())
        if m:
            total += int(m.group(1))
    return total, p.stdout


def by_area(work: Path, tag: str) -> dict[str, int]:
    """The own instructions of every function in `tag`'s cachegrind files, by area."""
    got: dict[str, int] = {}
    for f in work.glob(f"{tag}.*.cg"):
        fn = None
        for line in f.read_text().splitlines():
            if line.startswith("fn="):
                fn = line[3:]
                area = next((a for a, rx in AREAS if rx.search(fn)), "other")
            elif fn is not None and line[:1].isdigit():
                parts = line.split()
                if len(parts) >= 2:
                    got[area] = got.get(area, 0) + int(parts[1])
    return got


def per_unit(a: dict[str, int], b: dict[str, int], units: float) -> dict[str, float]:
    """(a - b) / units for each area, largest first."""
    d = {k: (a.get(k, 0) - b.get(k, 0)) / units for k in set(a) | set(b)}
    return {k: round(v, 1) for k, v in sorted(d.items(), key=lambda kv: -kv[1])}


def bench_run(bin_: str, variant: str, scenario: str, duration_ns: int, work: Path,
              channels: str | None) -> dict:
    argv = [bin_, "bench-run", "--variant", variant, "--duration-ns", str(duration_ns),
            "--record", str(work / f"{variant}.mcap"), scenario]
    if channels and variant == "recorded":
        argv += ["--channels", channels]
    instr, out = cachegrind(argv, work, variant)
    figures = json.loads(out.strip().splitlines()[-1])
    figures["by_area"] = by_area(work, variant)
    figures.pop("cpu_s", None)
    figures.pop("wall_s", None)
    # Under valgrind: its own memory, not the twin's (`m6p-twin bench` gives the peak).
    figures.pop("peak_rss_mib", None)
    figures["instructions"] = instr
    return figures


def round_trips(bin_: str, counts: tuple[int, int], work: Path) -> dict:
    got = []
    for n in counts:
        instr, out = cachegrind([bin_, "bench-run", "--variant", "round_trips", "--count", str(n)],
                                work, f"rt{n}")
        got.append((n, instr, json.loads(out.strip().splitlines()[-1])))
    (n0, i0, _), (n1, i1, f1) = got
    areas = per_unit(by_area(work, f"rt{n1}"), by_area(work, f"rt{n0}"), n1 - n0)
    return {
        "by_area": areas,
        "payload_bytes": 64,
        "counts": [n0, n1],
        "instructions": [i0, i1],
        "sim_s_per_round_trip": f1["sim_s"] / n1,
        "instructions_per_round_trip": (i1 - i0) / (n1 - n0),
    }


def campaign(bin_: str, file: str, runs: tuple[int, int], work: Path) -> dict:
    got = []
    for n in runs:
        out_dir = work / f"campaign-{n}"
        instr, _ = cachegrind([bin_, "campaign", "run", file, "--runs", str(n), "--jobs", "1",
                               "--out", str(out_dir)], work, f"campaign{n}")
        got.append((n, instr))
    (n0, i0), (n1, i1) = got
    return {
        "file": file,
        "runs": [n0, n1],
        "instructions": [i0, i1],
        "instructions_per_run": (i1 - i0) / (n1 - n0),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    built = ROOT / "target" / "release" / "m6p-twin"
    ap.add_argument("binary", nargs="?",
                    default=str(built) if built.exists() else shutil.which("m6p-twin"),
                    help="the m6p-twin to count (default: target/release/m6p-twin, else the one on PATH)")
    ap.add_argument("--scenario", default="scenarios/full-day.toml")
    ap.add_argument("--duration", default="1h", help="simulated span of each variant (default 1h)")
    ap.add_argument("--round-trips", default="1000,11000",
                    help="the two round-trip counts whose difference is counted")
    ap.add_argument("--campaign", default="campaigns/pc-sessions.toml")
    ap.add_argument("--campaign-runs", default="1,5",
                    help="the two run counts whose difference is counted")
    ap.add_argument("--only", default="plain,recorded,adcs_floor,round_trips,campaign",
                    help="what to count, comma-separated")
    ap.add_argument("--jobs", type=int, default=2, help="processes under valgrind at once")
    ap.add_argument("--channels", help="the recorded run's channels, as `m6p-twin run --channels`")
    args = ap.parse_args()
    if not shutil.which("valgrind"):
        print("valgrind is not installed (apt-get install valgrind)", file=sys.stderr)
        return 2
    if not args.binary:
        print("no m6p-twin: build it (cargo build --release) or name it", file=sys.stderr)
        return 2
    bin_ = str(Path(args.binary).resolve())
    only = set(args.only.split(","))
    duration_ns = parse_duration_ns(args.duration)
    t0 = time.monotonic()
    result: dict = {
        "binary": bin_,
        "scenario": args.scenario,
        "duration_s": duration_ns / 1e9,
        "channels": args.channels or "",
        "valgrind": subprocess.run(["valgrind", "--version"], check=False, capture_output=True,
                                   text=True).stdout.strip(),
    }
    with tempfile.TemporaryDirectory(prefix="m6p-perf-") as tmp:
        work = Path(tmp)
        jobs = {}
        with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
            for v in ("plain", "recorded", "adcs_floor"):
                if v in only:
                    jobs[v] = pool.submit(bench_run, bin_, v, args.scenario, duration_ns, work,
                                          args.channels)
            if "round_trips" in only:
                a, b = (int(x) for x in args.round_trips.split(","))
                jobs["round_trips"] = pool.submit(round_trips, bin_, (a, b), work)
            if "campaign" in only:
                a, b = (int(x) for x in args.campaign_runs.split(","))
                jobs["campaign"] = pool.submit(campaign, bin_, args.campaign, (a, b), work)
            variants = {k: f.result() for k, f in jobs.items()
                        if k in ("plain", "recorded", "adcs_floor")}
            result["variants"] = variants
            for k in ("round_trips", "campaign"):
                if k in jobs:
                    result[k] = jobs[k].result()
    plain, rec, floor = (variants.get(k) for k in ("plain", "recorded", "adcs_floor"))
    derived: dict = {}
    if plain:
        # A build before bench-run counted its frames has none to give.
        frames = sum(plain.get("can_frames", {}).values())
        derived["can_frames"] = frames
        derived["ground_packets"] = plain.get("ground_packets", 0)
        if floor and frames:
            derived["network_instructions_per_can_frame"] = (
                (plain["instructions"] - floor["instructions"]) / frames)
            derived["network_instructions_per_can_frame_by_area"] = per_unit(
                plain["by_area"], floor["by_area"], frames)
    if plain and rec:
        extra = rec["instructions"] - plain["instructions"]
        derived["recorder_instructions"] = extra
        derived["recorder_share_of_plain"] = extra / plain["instructions"]
        if rec.get("messages"):
            derived["recorder_instructions_per_message"] = extra / rec["messages"]
            derived["recorder_instructions_per_mcap_byte"] = extra / rec["mcap_bytes"]
    if "round_trips" in result:
        derived["instructions_per_round_trip"] = result["round_trips"]["instructions_per_round_trip"]
        derived["instructions_per_round_trip_by_area"] = result["round_trips"]["by_area"]
    if "campaign" in result:
        derived["campaign_instructions_per_run"] = result["campaign"]["instructions_per_run"]
    result["derived"] = derived
    result["wall_s"] = round(time.monotonic() - t0, 1)
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
