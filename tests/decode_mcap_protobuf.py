#!/usr/bin/env python3
"""Decode every message of an m6p-twin recording with Google's protobuf implementation, as
Foxglove and other protobuf-aware MCAP readers do: the `mcap` and `mcap-protobuf-support`
PyPI packages, the schemas in the file, nothing from this project.

Usage: python3 tests/decode_mcap_protobuf.py FILE.mcap

Checks that every message decodes, that the message counts equal the file's statistics,
and that every CAN train's data holds its frames' lengths. Prints the count per channel,
then `ok`; exits 1 with a reason on any failure.
"""
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def main() -> None:
    if len(sys.argv) != 2:
        sys.exit("usage: decode_mcap_protobuf.py FILE.mcap")
    counts = {}
    with open(sys.argv[1], "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        stats = reader.get_summary().statistics
        for _, channel, _, msg in reader.iter_decoded_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic.startswith("/can/") and channel.topic.endswith("/frames"):
                if len(msg.data) != sum(msg.dlc) or len(msg.can_id) != len(msg.end_ns):
                    print(f"FAIL: {channel.topic}: a train of {len(msg.can_id)} frames")
                    sys.exit(1)
    if sum(counts.values()) != stats.message_count:
        print(f"FAIL: decoded {sum(counts.values())} of {stats.message_count} messages")
        sys.exit(1)
    for topic, n in sorted(counts.items()):
        print(f"{topic} {n}")
    print("ok")


if __name__ == "__main__":
    main()
