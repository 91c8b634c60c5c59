#!/usr/bin/env python3
"""Record every shipped scenario and check its recording is in log-time order, run to run.

    tools/recording-order.py [M6P_TWIN_BIN] [--scenarios DIR] [--keep DIR]

For each `scenarios/*.toml` (or DIR's): `m6p-twin run FILE --record OUT`, then the file is
read front to back as a streaming reader reads it (the `mcap` package's StreamReader, the
chunks decompressed in file order) and every message's log time must be at or after the
previous one's, and every chunk's start time at or after the previous chunk's: what the
mcap tooling's `doctor --strict-message-order` requires. The default scenario is recorded a
second time and must be byte-identical. Exit 1 on any failure, naming the file, the
message's topic and its log time against the latest before it.

The binary: the argument, else $M6P_TWIN_BIN, else `m6p-twin` on the PATH. A release build
records the 25 shipped scenarios in about 30 s. Needs the `mcap` package (pip install mcap).
"""

from __future__ import annotations

import argparse
import filecmp
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import StreamReader

ROOT = Path(__file__).resolve().parent.parent


def out_of_order(path: Path) -> tuple[int, int, list[str]]:
    """Messages read, how many came earlier than the latest before them, and the first few
    of those described (chunks first: their start times, read without decompressing)."""
    late = 0
    bad: list[str] = []
    last_chunk = 0
    with open(path, "rb") as f:
        for rec in StreamReader(f, emit_chunks=True).records:
            if isinstance(rec, Chunk):
                if rec.message_start_time < last_chunk:
                    late += 1
                    bad.append(f"a chunk starting at {rec.message_start_time} after one at {last_chunk}")
                last_chunk = max(last_chunk, rec.message_start_time)
    topics: dict[int, str] = {}
    last = 0
    n = 0
    with open(path, "rb") as f:
        for rec in StreamReader(f).records:
            if isinstance(rec, Channel):
                topics[rec.id] = rec.topic
            elif isinstance(rec, Message):
                n += 1
                if rec.log_time < last:
                    late += 1
                    if len(bad) < 5:
                        bad.append(
                            f"{topics.get(rec.channel_id, rec.channel_id)} at {rec.log_time} "
                            f"after {last} ({(last - rec.log_time) / 1e9:.6f} s earlier)"
                        )
                last = max(last, rec.log_time)
    return n, late, bad


def record(twin: str, scenario: Path, out: Path) -> None:
    r = subprocess.run([twin, "run", str(scenario), "--record", str(out)],
                       capture_output=True, text=True, cwd=ROOT)
    if r.returncode not in (0, 1) or not out.is_file():
        sys.exit(f"recording-order: {scenario}: `m6p-twin run` exited {r.returncode}:\n{r.stderr[-2000:]}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("twin", nargs="?", default=os.environ.get("M6P_TWIN_BIN", "m6p-twin"))
    ap.add_argument("--scenarios", type=Path, default=ROOT / "scenarios")
    ap.add_argument("--keep", type=Path, help="record here (kept) instead of a temporary folder")
    args = ap.parse_args()
    files = sorted(args.scenarios.glob("*.toml"))
    if not files:
        sys.exit(f"recording-order: no scenarios in {args.scenarios}")
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="m6p-order-") as tmp:
        out_dir = args.keep or Path(tmp)
        out_dir.mkdir(parents=True, exist_ok=True)
        failed = 0
        total = 0
        for s in files:
            out = out_dir / f"{s.stem}.mcap"
            out.unlink(missing_ok=True)
            record(args.twin, s, out)
            n, late, bad = out_of_order(out)
            total += n
            status = "ok" if late == 0 else f"FAIL: {late} out of order"
            print(f"{s.stem:24} {n:9} messages  {status}")
            for b in bad:
                print(f"    {b}")
            failed += late > 0
        default = next((s for s in files if s.stem == "default"), files[0])
        again = out_dir / f"{default.stem}.again.mcap"
        again.unlink(missing_ok=True)
        record(args.twin, default, again)
        same = filecmp.cmp(out_dir / f"{default.stem}.mcap", again, shallow=False)
        print(f"{default.stem} recorded twice: {'byte-identical' if same else 'FAIL: the files differ'}")
        failed += not same
    print(f"{len(files)} recordings, {total} messages, {failed} failed, in {time.monotonic() - t0:.0f} s")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
