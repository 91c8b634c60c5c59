#!/usr/bin/env python3
"""A payload of the M6P written outside the twin, in Python, on the project's `m6p`
package (python/: `pip install ./python`; from a checkout it is found without installing).

It connects to the twin over TCP (KISS, CSP 1.4, as libcsp 1.4 frames them), takes the
place of payload 12 on the payload CAN bus, and does what ICD 3.1.8.2 asks of a payload in
a polling session of the payload controller (PC, CSP 6):

    SYNC  request  01 | message (0-128 bytes)   reply  01 01 | message (the same bytes)
    POLL  request  02 | frameSize (1 byte)      reply  02 01 | data (1 to frameSize bytes)

(`m6p.session.Payload`; replies go back to the request's source address and port, from the
port the request came to, with its priority and flags, and a CSP CRC when the request had
one). It also answers CSP pings (port 1), as any libcsp node does (`m6p.node.CspNode`).

Its data is a deterministic stream (`m6p.session.counter_frames`): frame number `seq` is
`seq` as u16 little-endian followed by a byte counter starting at `seq`, and its length
cycles through all, two thirds and one third of the frameSize the PC asks for. Every data
byte it puts in a POLL reply is written to the file given with `--sent`, in order, so that
what the twin downlinked over the S-band can be compared with it byte for byte.

It stops when the session is over (no POLL for `--idle` seconds after the first one), when
the twin closes the connection (end of its run), or after `--seconds`. Exit status: 0 when
it served a session (at least one SYNC and one POLL) and received no damaged frame, 1
otherwise, 2 when it could not connect.

Run it against the twin (from the repository root; examples/README.md has the scenario):

    # 1. the scenario: a KISS/TCP server for address 12 and a SETUP of session 1 at t = 2 s
    #    (copy the `cat > /tmp/outside_payload.toml` block of examples/README.md)
    # 2. build the twin, then start the payload: it keeps trying to connect for --wait s
    cargo build --release -p m6p-twin
    python3 examples/outside_payload.py --connect 127.0.0.1:52001 --sent /tmp/sent.bin &
    # 3. the twin, which writes what reached the ground to /tmp/outside_payload.downlink/
    target/release/m6p-twin run /tmp/outside_payload.toml
    wait
    cmp /tmp/sent.bin /tmp/outside_payload.downlink/session-1-run1.bin && echo identical

The test crates/twin/tests/outside_payload.rs runs that scenario with this script and
checks the downlink byte for byte (`cargo test -p m6p-twin --test outside_payload`). The
same payload in a pytest file is python/tests/test_payload_session.py.
"""
import argparse
import os
import sys
import time

try:
    import m6p  # noqa: F401
except ImportError:  # a checkout without `pip install ./python`
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python", "src"))

from m6p.links import KissTcp  # noqa: E402
from m6p.node import CspNode  # noqa: E402
from m6p.session import Payload, counter_frames  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--connect", default="127.0.0.1:52001",
                    help="the twin's KISS/TCP server, HOST:PORT (default %(default)s)")
    ap.add_argument("--addr", type=int, default=12,
                    help="this payload's CSP address, 12-15 (default %(default)s)")
    ap.add_argument("--port", type=int, default=10,
                    help="the SYNC/POLL port (default %(default)s)")
    ap.add_argument("--sent", metavar="FILE",
                    help="write every data byte sent in POLL replies to FILE (binary, in order)")
    ap.add_argument("--idle", type=float, default=3.0,
                    help="stop after this many seconds without a POLL (default %(default)s)")
    ap.add_argument("--seconds", type=float, default=None,
                    help="stop after this many seconds whatever happens")
    ap.add_argument("--wait", type=float, default=60.0,
                    help="keep trying to connect for this long (default %(default)s s)")
    a = ap.parse_args()

    try:
        link = KissTcp(a.connect, connect_timeout_s=a.wait)
    except OSError as e:
        print(f"cannot connect to {a.connect}: {e}", file=sys.stderr)
        return 2
    print(f"connected to {a.connect} as CSP {a.addr}, serving port {a.port}", flush=True)

    def on_sync(message: bytes) -> bool:
        print(f"SYNC {message!r}: acknowledged", flush=True)
        return True

    node = CspNode(link, a.addr)
    payload = Payload(node, port=a.port, source=counter_frames(), on_sync=on_sync)
    start = time.monotonic()
    while True:
        now = time.monotonic()
        if a.seconds is not None and now - start >= a.seconds:
            why = f"{a.seconds} s elapsed"
            break
        if payload.last_poll is not None and now - payload.last_poll >= a.idle:
            why = f"no POLL for {a.idle} s: the session is over"
            break
        if node.closed.wait(0.05):
            why = "the twin closed the connection"
            break
    node.close()
    if a.sent:
        with open(a.sent, "wb") as f:
            f.write(payload.sent)
    damaged = link.decoder.rx_errors
    print(f"stopped ({why}): {len(payload.syncs)} SYNC, {payload.polls} POLL, "
          f"{len(payload.sent)} data bytes sent, {payload.refused} refused, "
          f"{damaged} damaged frames", flush=True)
    served = payload.syncs and payload.polls > 0
    return 0 if served and damaged == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
