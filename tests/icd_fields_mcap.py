#!/usr/bin/env python3
"""Plot-style check of the decoded ICD fields in a recording, with only the `mcap` package.

    python3 tests/icd_fields_mcap.py REC.mcap NODE.COMMAND FIELD

Prints one line per reply of NODE.COMMAND on the ground network: `t_s value text` of FIELD
(`/csp/packets`, `icd == NODE.COMMAND`, `icd_kind == "reply"`, the field named FIELD in
`fields`), what a Foxglove plot of `/csp/packets{icd=="FC.TMGEN"}.fields[:]{name=="current_mode"}.value`
shows. The schemas come from the file (tests/decode_mcap.py's decoder).
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import decode_mcap as d  # noqa: E402
from mcap.reader import make_reader  # noqa: E402


def main() -> None:
    path, command, field = sys.argv[1:4]
    schemas = {}
    rows = 0
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=["/csp/packets"]):
            if schema.id not in schemas:
                schemas[schema.id] = d.parse_descriptor_set(schema.data)
            p = d.decode(schemas[schema.id], schema.name, message.data)
            if p["icd"] != command or p["icd_kind"] != "reply" or p["medium"] != "ground":
                continue
            hit = [x for x in p["fields"] if x["name"] == field]
            if len(hit) != 1:
                d.fail(f"{command} reply at {p['t_ns']} ns has {len(hit)} fields named {field}")
            print(f"{p['t_ns'] / 1e9:.3f} {hit[0]['value']} {hit[0]['text']}")
            rows += 1
    if rows == 0:
        d.fail(f"no {command} reply on the ground network")


if __name__ == "__main__":
    main()
