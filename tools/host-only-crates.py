#!/usr/bin/env python3
"""The crates that only run at build time (proc macros, build scripts and what they use),
from `cargo metadata`, against the `[profile.dev.package]` table of the workspace's
Cargo.toml: `"*"` at opt-level 2 and each of those crates at opt-level 0.

Why: Cargo.toml builds dependencies at opt-level 2 (`"*"`) so that the tests run fast, and
a `package."*"` override outranks `build-override`, so without the list the proc macros,
syn and the build scripts' helpers were optimised too: about 420 s of cargo's unit time in
a fresh test build, for code that runs for seconds (docs/architecture.md, "Build profiles").

    tools/host-only-crates.py          check: exit 1, name the difference, print the lines
    tools/host-only-crates.py --toml   print the build-time crates' lines of the table

A crate used both at build time and in the twin (anyhow, libc) is not on the list: it keeps
opt-level 2, and so do the build scripts of the twin's own dependencies. `cargo metadata`'s
resolve also holds optional crates that only a weak feature (`dep?/feature`) names and that
are never built (borsh-derive, time-macros); they are listed, harmlessly. Run from the
workspace root; needs cargo and Python 3.11 or later (`tomllib`).
"""

import json
import subprocess
import sys
import tomllib

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


def table_problems(cargo_toml, want):
    """What is wrong with the `[profile.dev.package]` table against `want`, as lines."""
    profiles = tomllib.loads(cargo_toml).get("profile", {})
    table = profiles.get("dev", {}).get("package", {})
    problems = []
    if "*" not in table:
        problems.append('[profile.dev.package] has no "*" = { opt-level = 2 }')
    elif table["*"] != {"opt-level": 2}:
        problems.append(f'[profile.dev.package] "*" is {table["*"]!r}, not {{ opt-level = 2 }}')
    # The test profile inherits the dev one; its own overrides would win over this table.
    tests = profiles.get("test", {}).get("package", {})
    overridden = sorted(name for name in tests if name == "*" or name in want)
    if overridden:
        problems.append(
            "[profile.test.package] overrides the table for tests: " + " ".join(overridden)
        )
    have = {name for name, v in table.items() if name != "*" and v == {"opt-level": 0}}
    other = sorted(name for name, v in table.items() if name != "*" and v != {"opt-level": 0})
    if other:
        problems.append("[profile.dev.package] not { opt-level = 0 }: " + " ".join(other))
    missing = sorted(set(want) - have)
    if missing:
        problems.append("build-time crates not at opt-level 0: " + " ".join(missing))
    extra = sorted(have - set(want))
    if extra:
        problems.append("at opt-level 0 but not build-time only: " + " ".join(extra))
    return problems


def lines(want):
    return [f"{name} = {{ opt-level = 0 }}" for name in want]


def main():
    try:
        out = subprocess.run(
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
            stdout=subprocess.PIPE,
            text=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError) as e:
        print(f"tools/host-only-crates.py: cargo metadata failed: {e}")
        return 2
    want = host_only(json.loads(out))
    if sys.argv[1:] == ["--toml"]:
        print("\n".join(lines(want)))
        return 0
    with open("Cargo.toml", "rb") as f:
        text = f.read().decode("utf-8")
    try:
        problems = table_problems(text, want)
    except tomllib.TOMLDecodeError as e:
        # cargo reads TOML 1.1 (a trailing comma in an inline table), tomllib only 1.0.
        print(f"Cargo.toml: Python's tomllib (TOML 1.0) cannot read it: {e}")
        return 2
    if problems:
        for p in problems:
            print(f"Cargo.toml: {p}")
        print('The build-time crates\' lines (after `"*" = { opt-level = 2 }`):')
        print("\n".join(lines(want)))
        return 1
    print(f"Cargo.toml: the {len(want)} build-time crates are at opt-level 0")
    return 0


if __name__ == "__main__":
    sys.exit(main())
