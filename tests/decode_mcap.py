#!/usr/bin/env python3
"""Decode an m6p-twin recording with nothing but the `mcap` PyPI package and the schemas in
the file.

Usage: python3 tests/decode_mcap.py FILE.mcap

Checks, as a generic MCAP reader would see the file (no code from this project):
- every channel has a schema whose encoding is `protobuf` and whose data is a
  `FileDescriptorSet` holding the message the schema names;
- every message's channel uses the `protobuf` message encoding and every message decodes
  with its schema alone (a protobuf decoder written here from the wire format: varints,
  fixed 32/64-bit, length-delimited fields, packed or not; `bytes` become hex strings,
  Foxglove times `{sec, nsec}`, absent fields with presence None);
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
import struct
import sys

from mcap.reader import make_reader


def fail(why: str) -> None:
    print(f"FAIL: {why}")
    sys.exit(1)


# --- protobuf, from the wire format (https://protobuf.dev/programming-guides/encoding/) ---

# FieldDescriptorProto.type values used below.
T_DOUBLE, T_FLOAT, T_INT64, T_UINT64, T_INT32, T_FIXED64, T_FIXED32, T_BOOL = 1, 2, 3, 4, 5, 6, 7, 8
T_STRING, T_GROUP, T_MESSAGE, T_BYTES, T_UINT32, T_ENUM = 9, 10, 11, 12, 13, 14
T_SFIXED32, T_SFIXED64, T_SINT32, T_SINT64 = 15, 16, 17, 18
LABEL_REPEATED = 3


def varint(b: bytes, i: int):
    v, shift = 0, 0
    while True:
        if i >= len(b) or shift > 63:
            raise ValueError("truncated varint")
        c = b[i]
        i += 1
        v |= (c & 0x7F) << shift
        shift += 7
        if not c & 0x80:
            return v, i


def fields(b: bytes):
    """(number, wire type, value) of each field of one message."""
    i = 0
    while i < len(b):
        key, i = varint(b, i)
        num, wt = key >> 3, key & 7
        if wt == 0:
            v, i = varint(b, i)
        elif wt == 1:
            v, i = b[i:i + 8], i + 8
        elif wt == 2:
            n, i = varint(b, i)
            v, i = b[i:i + n], i + n
        elif wt == 5:
            v, i = b[i:i + 4], i + 4
        else:
            raise ValueError(f"wire type {wt}")
        if i > len(b):
            raise ValueError("field beyond the message")
        yield num, wt, v


def parse_descriptor_set(data: bytes) -> dict:
    """Full message name -> list of fields (name, number, label, type, type_name, optional)."""
    messages = {}

    def message(b: bytes, prefix: str) -> None:
        name, flds, nested = "", [], []
        for num, _, v in fields(b):
            if num == 1:
                name = v.decode()
            elif num == 2:
                f = {"name": "", "number": 0, "label": 1, "type": 0, "type_name": "", "optional": False}
                for n2, _, v2 in fields(v):
                    if n2 == 1:
                        f["name"] = v2.decode()
                    elif n2 == 3:
                        f["number"] = v2
                    elif n2 == 4:
                        f["label"] = v2
                    elif n2 == 5:
                        f["type"] = v2
                    elif n2 == 6:
                        f["type_name"] = v2.decode()
                    elif n2 == 17:
                        f["optional"] = bool(v2)
                flds.append(f)
            elif num == 3:
                nested.append(v)
        full = f"{prefix}.{name}" if prefix else name
        messages[full] = flds
        for n in nested:
            message(n, full)

    for num, _, file in fields(data):
        if num != 1:
            continue
        package, types = "", []
        for n, _, v in fields(file):
            if n == 2:
                package = v.decode()
            elif n == 4:
                types.append(v)
        for t in types:
            message(t, package)
    return messages


def resolve(messages: dict, scope: str, type_name: str) -> str:
    if type_name.startswith("."):
        return type_name[1:]
    while True:
        cand = f"{scope}.{type_name}" if scope else type_name
        if cand in messages:
            return cand
        if not scope:
            raise ValueError(f"unknown type {type_name}")
        scope = scope.rpartition(".")[0]


def f32_decimal(v: bytes) -> float:
    """A single-precision value as its shortest decimal (0.1, not 0.10000000149011612), as
    the twin's own decoder gives it."""
    x = struct.unpack("<f", v)[0]
    if x != x or abs(x) == float("inf"):
        return x
    for digits in range(1, 10):
        d = float(f"{x:.{digits}g}")
        if struct.pack("<f", d) == v:
            return d
    return x


def scalar(ty: int, wt: int, v):
    if ty == T_DOUBLE:
        x = struct.unpack("<d", v)[0]
    elif ty == T_FLOAT:
        x = f32_decimal(v)
    elif ty in (T_STRING,):
        return v.decode("utf-8", "replace")
    elif ty == T_BYTES:
        return v.hex()
    elif ty == T_BOOL:
        return v != 0
    elif ty in (T_SINT32, T_SINT64):
        return (v >> 1) ^ -(v & 1)
    elif ty in (T_INT32, T_INT64, T_ENUM):
        return v - (1 << 64) if v >= 1 << 63 else v
    elif ty in (T_FIXED32, T_SFIXED32):
        x = struct.unpack("<I" if ty == T_FIXED32 else "<i", v)[0]
        return x
    elif ty in (T_FIXED64, T_SFIXED64):
        return struct.unpack("<Q" if ty == T_FIXED64 else "<q", v)[0]
    else:
        return v
    return x if x == x and abs(x) != float("inf") else None


def decode(messages: dict, name: str, b: bytes) -> dict:
    """One message as a dict (the twin's JSON view: see the module docstring)."""
    flds = messages[name]
    by_num = {f["number"]: f for f in flds}
    out = {}
    for num, wt, v in fields(b):
        f = by_num.get(num)
        if f is None:
            continue
        ty = f["type"]
        if ty == T_MESSAGE:
            val = decode(messages, resolve(messages, name, f["type_name"]), v)
        if f["label"] == LABEL_REPEATED:
            items = out.setdefault(f["name"], [])
            if ty == T_MESSAGE:
                items.append(val)
            elif wt == 2 and ty not in (T_STRING, T_BYTES):
                size = {T_DOUBLE: 8, T_FIXED64: 8, T_SFIXED64: 8, T_FLOAT: 4, T_FIXED32: 4, T_SFIXED32: 4}.get(ty)
                if size:
                    items.extend(scalar(ty, 0, v[k:k + size]) for k in range(0, len(v), size))
                else:
                    i = 0
                    while i < len(v):
                        x, i = varint(v, i)
                        items.append(scalar(ty, 0, x))
            else:
                items.append(scalar(ty, wt, v))
        else:
            out[f["name"]] = val if ty == T_MESSAGE else scalar(ty, wt, v)
    for f in flds:
        if f["name"] in out:
            continue
        if f["label"] == LABEL_REPEATED:
            out[f["name"]] = []
        elif f["optional"] or f["type"] == T_MESSAGE:
            out[f["name"]] = None
        elif f["type"] in (T_STRING, T_BYTES):
            out[f["name"]] = ""
        elif f["type"] == T_BOOL:
            out[f["name"]] = False
        elif f["type"] in (T_DOUBLE, T_FLOAT):
            out[f["name"]] = 0.0
        else:
            out[f["name"]] = 0
    if name in ("google.protobuf.Timestamp", "google.protobuf.Duration"):
        out = {"sec": out.get("seconds", 0), "nsec": out.get("nanos", 0)}
    return out


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
        if msg["translation"] is not None and any(msg["translation"][k] != 0 for k in "xyz"):
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
        types = {}  # schema id -> parsed FileDescriptorSet
        for cid, ch in sorted(summary.channels.items()):
            schema = summary.schemas.get(ch.schema_id)
            if schema is None:
                fail(f"channel {ch.topic} has no schema")
            if schema.encoding != "protobuf":
                fail(f"channel {ch.topic}: schema encoding {schema.encoding!r}")
            try:
                types[schema.id] = parse_descriptor_set(schema.data)
            except (ValueError, IndexError, UnicodeDecodeError) as e:
                fail(f"schema {schema.name} is not a FileDescriptorSet: {e}")
            if schema.name not in types[schema.id]:
                fail(f"schema {schema.name} does not hold its message")
            if ch.message_encoding != "protobuf":
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
        frames = 0  # CAN frames in all the trains
        start_ns = None  # log time - t_ns, from the first message with a t_ns
        for schema, channel, message in reader.iter_messages():
            try:
                msg = decode(types[schema.id], schema.name, message.data)
            except (ValueError, IndexError, KeyError, struct.error) as e:
                fail(f"{channel.topic}: message {counts[channel.topic]} does not decode: {e}")
            counts[channel.topic] += 1
            if start_ns is None and isinstance(msg.get("t_ns"), int):
                start_ns = message.log_time - msg["t_ns"]
            if channel.topic == "/ground/packets":
                raw = bytes.fromhex(msg["bytes"])
                if not msg["dropped"] and len(raw) >= 4:
                    ground.append(raw)
            elif channel.topic in FOXGLOVE_SCHEMAS:
                check_truth(channel.topic, msg, message.log_time)
                if channel.topic == "/fc/truth/state":
                    truth_t.append(msg["t_ns"])
                elif channel.topic == "/fc/adcs":
                    adcs_t.append(msg["t_ns"])
            elif channel.topic.startswith("/can/") and channel.topic.endswith("/frames"):
                n = len(msg["can_id"])
                if not (n == len(msg["dlc"]) == len(msg["end_ns"]) and n > 0):
                    fail(f"{channel.topic}: a train of {n} ids, {msg['dlc']} lengths, {msg['end_ns']} ends")
                if len(bytes.fromhex(msg["data"])) != sum(msg["dlc"]):
                    fail(f"{channel.topic}: {len(msg['data']) // 2} data bytes for lengths {msg['dlc']}")
                if message.log_time != start_ns + msg["t_ns"] if start_ns is not None else False:
                    fail(f"{channel.topic}: log time {message.log_time} for t_ns {msg['t_ns']}")
                frames += n
            elif channel.topic == "/csp/packets" and msg["medium"] == "ground":
                data = bytes.fromhex(msg["data"])
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
    print(f"CAN frames checked: {frames}")
    print(f"ground packets checked: {len(ground)}")
    print(f"truth samples checked: {len(truth_t)}")
    print("ok")


if __name__ == "__main__":
    main()
