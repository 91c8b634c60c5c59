#!/usr/bin/env python3
"""Compare two MCAP recordings channel by channel.

    tools/recording-channels.py A.mcap B.mcap

For every topic: the number of messages and a digest of their log times and bytes; prints
the topics that differ (or exist in one file only) and whether the metadata records
differ, and exits 1 when anything differs. `m6p-twin diff` compares the media channels'
traffic and stops at the first divergence; this names every channel that differs, which is
how a change of recorded behaviour is named channel by channel (issue 41's comparison
with f80b656). Needs the `mcap` package (pip install mcap).
"""

from __future__ import annotations

import hashlib
import sys

from mcap.reader import make_reader


def load(path: str) -> tuple[dict[str, tuple[int, str]], dict[str, dict[str, str]]]:
    topics: dict[str, tuple[int, hashlib._Hash]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for _schema, channel, message in reader.iter_messages(log_time_order=False):
            n, h = topics.get(channel.topic, (0, hashlib.sha256()))
            h.update(message.log_time.to_bytes(8, "little"))
            h.update(message.data)
            topics[channel.topic] = (n + 1, h)
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return {t: (n, h.hexdigest()) for t, (n, h) in topics.items()}, meta


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        return 2
    (a, meta_a), (b, meta_b) = load(sys.argv[1]), load(sys.argv[2])
    differs = False
    for topic in sorted(set(a) | set(b)):
        if a.get(topic) != b.get(topic):
            differs = True
            na, nb = a.get(topic, (0, ""))[0], b.get(topic, (0, ""))[0]
            only = "" if topic in a and topic in b else " (in one file only)"
            print(f"{topic}: {na} vs {nb} messages{only}")
    if meta_a != meta_b:
        differs = True
        print("metadata differs")
    if not differs:
        print(f"identical channel by channel ({len(a)} topics)")
    return 1 if differs else 0


if __name__ == "__main__":
    sys.exit(main())
