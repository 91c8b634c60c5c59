#!/usr/bin/env python3
"""Decode an m6p-twin recording with nothing but the `mcap` PyPI package and json.

Usage: python3 tests/decode_mcap.py FILE.mcap

Checks, as a generic MCAP reader would see the file (no code from this project):
- every channel has a schema whose encoding is `jsonschema` and whose data is JSON;
- every message's channel uses the `json` message encoding and every message decodes as JSON;
- the `m6p-twin` metadata and the `scenario.toml` attachment are there;
- every `/csp/packets` message on the ground medium has the same bytes (header rebuilt from
  its fields, then data) as the matching `/ground/packets` message: the n-th delivered
  packet is the n-th ground packet that was not dropped and holds a whole header;
- the FC truth channels (docs/recording.md), when present: Foxglove schema names, the
  transforms `eci` -> `body` / `body_est` with a unit quaternion, no translation and a
  `timestamp` equal to the log time; the location in range in frame `earth`; the scene in
  frame `body`; one `/fc/adcs` message per `/fc/truth/state` message, at the same `t_ns`.

Prints the message count per channel, then `ok`; exits 1 with a reason on any failure.
"""
import json
import sys

from mcap.reader import make_reader


def fail(why: str) -> None:
    print(f"FAIL: {why}")
    sys.exit(1)


def header_word(p: dict) -> int:
    """The CSP 1.x header word from decoded fields (docs/protocol.md)."""
    return (
        (p["prio"] & 0x3) << 30
        | (p["src"] & 0x1F) << 25
        | (p["dst"] & 0x1F) << 20
        | (p["dport"] & 0x3F) << 14
        | (p["sport"] & 0x3F) << 8
        | (p["flags"] & 0xFF)
    )


FOXGLOVE_SCHEMAS = {
    "/fc/truth/tf": "foxglove.FrameTransform",
    "/fc/estimate/tf": "foxglove.FrameTransform",
    "/fc/truth/location": "foxglove.LocationFix",
    "/fc/scene": "foxglove.SceneUpdate",
    "/fc/truth/state": "m6p.TruthState",
    "/fc/adcs": "m6p.Adcs",
}


def stamp_ns(msg: dict) -> int:
    return msg["timestamp"]["sec"] * 1_000_000_000 + msg["timestamp"]["nsec"]


def check_truth(topic: str, msg: dict, log_time: int) -> None:
    """Check one message of an FC truth channel."""
    if topic in ("/fc/truth/tf", "/fc/estimate/tf"):
        child = "body" if topic == "/fc/truth/tf" else "body_est"
        if msg["parent_frame_id"] != "eci" or msg["child_frame_id"] != child:
            fail(f"{topic}: frames {msg['parent_frame_id']} -> {msg['child_frame_id']}")
        q = msg["rotation"]
        norm = (q["x"] ** 2 + q["y"] ** 2 + q["z"] ** 2 + q["w"] ** 2) ** 0.5
        if abs(norm - 1.0) > 1e-9:
            fail(f"{topic}: rotation norm {norm}")
        if any(msg["translation"][k] != 0 for k in "xyz"):
            fail(f"{topic}: translation {msg['translation']}")
        if stamp_ns(msg) != log_time:
            fail(f"{topic}: timestamp {stamp_ns(msg)} != log time {log_time}")
    elif topic == "/fc/truth/location":
        if msg["frame_id"] != "earth" or len(msg["position_covariance"]) != 9:
            fail(f"{topic}: frame {msg['frame_id']!r}")
        if not (-90 <= msg["latitude"] <= 90 and -180 <= msg["longitude"] <= 180):
            fail(f"{topic}: lat {msg['latitude']} lon {msg['longitude']}")
    elif topic == "/fc/scene":
        ents = msg["entities"]
        if len(ents) != 1 or ents[0]["frame_id"] != "body" or not ents[0]["cubes"]:
            fail(f"{topic}: entities {ents}")


def main() -> None:
    if len(sys.argv) != 2:
        fail("usage: decode_mcap.py FILE.mcap")
    with open(sys.argv[1], "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        if summary is None:
            fail("no summary section")
        for cid, ch in sorted(summary.channels.items()):
            schema = summary.schemas.get(ch.schema_id)
            if schema is None:
                fail(f"channel {ch.topic} has no schema")
            if schema.encoding != "jsonschema":
                fail(f"channel {ch.topic}: schema encoding {schema.encoding!r}")
            try:
                json.loads(schema.data)
            except ValueError as e:
                fail(f"schema {schema.name} is not JSON: {e}")
            if ch.message_encoding != "json":
                fail(f"channel {ch.topic}: message encoding {ch.message_encoding!r}")

        meta = [m for m in reader.iter_metadata() if m.name == "m6p-twin"]
        if len(meta) != 1 or "seed" not in meta[0].metadata:
            fail("no m6p-twin metadata with a seed")
        att = [a for a in reader.iter_attachments() if a.name == "scenario.toml"]
        if len(att) != 1:
            fail("no scenario.toml attachment")

        for _, ch in sorted(summary.channels.items()):
            want = FOXGLOVE_SCHEMAS.get(ch.topic)
            name = summary.schemas[ch.schema_id].name
            if want is not None and name != want:
                fail(f"channel {ch.topic}: schema {name!r}, expected {want!r}")

        counts = {ch.topic: 0 for _, ch in sorted(summary.channels.items())}
        truth_t = []  # t_ns of /fc/truth/state messages, in order
        adcs_t = []  # t_ns of /fc/adcs messages
        ground = []  # bytes of delivered ground packets, in order
        csp_ground = []  # bytes rebuilt from /csp/packets on the ground medium
        for schema, channel, message in reader.iter_messages():
            try:
                msg = json.loads(message.data)
            except ValueError as e:
                fail(f"{channel.topic}: message {counts[channel.topic]} is not JSON: {e}")
            counts[channel.topic] += 1
            if channel.topic == "/ground/packets":
                raw = bytes.fromhex(msg["bytes_hex"])
                if not msg["dropped"] and len(raw) >= 4:
                    ground.append(raw)
            elif channel.topic in FOXGLOVE_SCHEMAS:
                check_truth(channel.topic, msg, message.log_time)
                if channel.topic == "/fc/truth/state":
                    truth_t.append(msg["t_ns"])
                elif channel.topic == "/fc/adcs":
                    adcs_t.append(msg["t_ns"])
            elif channel.topic == "/csp/packets" and msg["medium"] == "ground":
                data = bytes.fromhex(msg["data_hex"])
                if len(data) != msg["len"]:
                    fail(f"/csp/packets: len {msg['len']} but {len(data)} data bytes")
                csp_ground.append(header_word(msg).to_bytes(4, "big") + data)

    if csp_ground != ground:
        for i, (a, b) in enumerate(zip(csp_ground, ground)):
            if a != b:
                fail(f"ground packet {i}: /csp/packets {a.hex()} != /ground/packets {b.hex()}")
        fail(f"{len(csp_ground)} ground CSP packets but {len(ground)} delivered ground packets")
    if truth_t != adcs_t:
        fail(f"/fc/truth/state at {truth_t} but /fc/adcs at {adcs_t}")
    for topic, n in counts.items():
        print(f"{topic} {n}")
    print(f"ground packets checked: {len(ground)}")
    print(f"truth samples checked: {len(truth_t)}")
    print("ok")


if __name__ == "__main__":
    main()
