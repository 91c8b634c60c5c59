#!/usr/bin/env python3
"""The crates that only run at build time (proc macros, build scripts and what they use),
from `cargo metadata`, against the `<name> = { opt-level = 0 }` lines of the
`[profile.dev.package]` table in the workspace's Cargo.toml.

Why: Cargo.toml builds dependencies at opt-level 2 (`[profile.dev.package."*"]`) so that the
tests run fast, and a `package."*"` override outranks `build-override`, so without the list
the proc macros, syn and the build scripts' helpers were optimised too: about 370 s of CPU in a fresh
build, for code that runs for seconds (docs/architecture.md, "Build profiles").

    tools/host-only-crates.py          check: exit 1 and name the difference
    tools/host-only-crates.py --toml   print the list as lines of that table

A crate used both at build time and in the twin (memchr, serde) is not on the list: it keeps
opt-level 2. Run from the workspace root; needs only cargo and Python's standard library.
"""

import json
import re
import subprocess
import sys

TRIPLE = "x86_64-unknown-linux-gnu"


def host_only(meta):
    pkgs = {p["id"]: p for p in meta["packages"]}
    nodes = {n["id"]: n for n in meta["resolve"]["nodes"]}
    members = set(meta["workspace_members"])

    def is_macro(pid):
        return any("proc-macro" in t["kind"] for t in pkgs[pid]["targets"])

    host, target = set(), set()
    todo = [(m, False) for m in members]
    seen = set()
    while todo:
        pid, at_build = todo.pop()
        if (pid, at_build) in seen:
            continue
        seen.add((pid, at_build))
        at_build = at_build or is_macro(pid)
        (host if at_build else target).add(pid)
        for d in nodes[pid]["deps"]:
            kinds = {k["kind"] for k in d["dep_kinds"]}
            # Dev dependencies count for workspace members only (cargo builds no others').
            for kind in kinds:
                if kind == "dev" and pid not in members:
                    continue
                todo.append((d["pkg"], at_build or kind == "build"))
    names = {pkgs[p]["name"] for p in host - target - members}
    # A name with one version at build time and another in the twin stays optimised.
    names -= {pkgs[p]["name"] for p in target}
    return sorted(names)


def listed(cargo_toml):
    """The names given `{ opt-level = 0 }` in the `[profile.dev.package]` table."""
    table = re.search(r"^\[profile\.dev\.package\]\n(.*?)(?=^\[|\Z)", cargo_toml, re.M | re.S)
    if table is None:
        return []
    return sorted(re.findall(r"^([A-Za-z0-9_-]+) = \{ opt-level = 0 \}$", table.group(1), re.M))


def main():
    meta = json.loads(
        subprocess.run(
            [
                "cargo",
                "metadata",
                "--format-version",
                "1",
                "--all-features",
                "--filter-platform",
                TRIPLE,
            ],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
    )
    want = host_only(meta)
    if sys.argv[1:] == ["--toml"]:
        for name in want:
            print(f"{name} = {{ opt-level = 0 }}")
        return 0
    with open("Cargo.toml", encoding="utf-8") as f:
        have = listed(f.read())
    missing = sorted(set(want) - set(have))
    extra = sorted(set(have) - set(want))
    if missing or extra:
        if missing:
            print("Cargo.toml: build-time crates built at opt-level 2:", " ".join(missing))
        if extra:
            print("Cargo.toml: listed at opt-level 0 but not build-time only:", " ".join(extra))
        print("tools/host-only-crates.py --toml prints the list")
        return 1
    print(f"Cargo.toml: the {len(want)} build-time crates are at opt-level 0")
    return 0


if __name__ == "__main__":
    sys.exit(main())
