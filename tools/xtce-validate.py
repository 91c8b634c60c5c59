#!/usr/bin/env python3
"""Validate an XTCE 1.2 mission database (`m6p-twin icd --xtce`) against the OMG schema.

The schema is XTCE 1.2's (`dtc-18-02-04.xsd`, namespace http://www.omg.org/spec/XTCE/20180204)
as PyPI's `xtce-lib` ships it (0.1.0a4, MIT, `xtce_lib/xsd/`, with the `xml.xsd` it imports
beside it, so nothing is fetched). Only its data files are used: install it with
`pip install --no-deps xtce-lib==0.1.0a4` beside `lxml` (.ci/run does).

Prints one JSON object: whether the file is valid, the schema's errors (line and message),
and the counts a test compares with `icd --json`: commands (MetaCommands that are not
abstract), reply containers (SequenceContainers named `reply` below a node), parameters.
Exit status 0 when valid, 1 when not, 2 when lxml or the schema is missing.

Usage: tools/xtce-validate.py FILE
"""

import importlib.util
import json
import sys
from pathlib import Path

XTCE = "http://www.omg.org/spec/XTCE/20180204"
SCHEMA = "dtc-18-02-04.xsd"


def schema_path() -> Path:
    spec = importlib.util.find_spec("xtce_lib")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("the xtce-lib package (pip install --no-deps xtce-lib==0.1.0a4)")
    for d in spec.submodule_search_locations:
        p = Path(d) / "xsd" / SCHEMA
        if p.is_file():
            return p
    raise FileNotFoundError(f"{SCHEMA} in the xtce-lib package")


def main() -> int:
    if len(sys.argv) != 2:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    try:
        from lxml import etree
    except ImportError:
        print("xtce-validate: needs lxml (pip install lxml)", file=sys.stderr)
        return 2
    try:
        xsd = schema_path()
    except FileNotFoundError as e:
        print(f"xtce-validate: needs {e}", file=sys.stderr)
        return 2
    schema = etree.XMLSchema(etree.parse(str(xsd)))
    doc = etree.parse(sys.argv[1])
    valid = schema.validate(doc)
    ns = {"x": XTCE}
    commands = doc.xpath("//x:MetaCommand[not(@abstract='true')]", namespaces=ns)
    replies = doc.xpath(
        "/x:SpaceSystem/x:SpaceSystem/x:SpaceSystem//x:SequenceContainer[@name='reply']",
        namespaces=ns,
    )
    params = doc.xpath("//x:Parameter", namespaces=ns)
    print(
        json.dumps(
            {
                "schema": f"xtce-lib {SCHEMA}",
                "valid": bool(valid),
                "errors": [f"line {e.line}: {e.message}" for e in schema.error_log],
                "commands": sorted(
                    c.getparent().getparent().getparent().get("name") + "." + c.get("name")
                    for c in commands
                ),
                "replies": sorted(
                    r.getparent().getparent().getparent().getparent().get("name")
                    + "."
                    + r.getparent().getparent().getparent().get("name")
                    for r in replies
                ),
                "parameters": len(params),
            },
            indent=1,
        )
    )
    return 0 if valid else 1


if __name__ == "__main__":
    sys.exit(main())
