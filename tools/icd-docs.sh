#!/usr/bin/env bash
# Regenerate what is generated from the twin's own wire types: the ICD tables of
# docs/protocol.md (between its BEGIN/END ICD tables markers) and the Python package's copy
# of the ICD (python/src/m6p/icd.json): tools/icd-docs.sh. The unit tests
# `icd::tests::docs_protocol_md_has_the_generated_tables` and
# `icd::tests::the_python_package_carries_the_current_icd` fail when they drift.
set -euo pipefail
cd "$(dirname "$0")/.."
tables=$(mktemp)
trap 'rm -f "$tables"' EXIT
cargo run -q -p m6p-twin -- icd --markdown >"$tables"
python3 - "$tables" <<'PY'
import sys
doc_path = "docs/protocol.md"
doc = open(doc_path).read()
tables = open(sys.argv[1]).read()
begin = next(l for l in doc.splitlines() if l.startswith("<!-- BEGIN ICD tables"))
end = "<!-- END ICD tables -->"
a = doc.index(begin) + len(begin)
b = doc.index(end)
open(doc_path, "w").write(doc[:a] + "\n" + tables + "\n" + doc[b:])
PY
cargo run -q -p m6p-twin -- icd --json >python/src/m6p/icd.json
echo "docs/protocol.md: ICD tables regenerated; python/src/m6p/icd.json written"
