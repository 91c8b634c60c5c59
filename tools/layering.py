#!/usr/bin/env python3
"""The workspace's layering check: dependencies point down only.

    tools/layering.py            check; exit 1 naming every violation
    tools/layering.py --graph    also print each crate's module graph (edges between siblings)

Three rules, read from the sources (nothing to build):

1. **Crates.** `tools/layers.toml` declares the layers, bottom first. A workspace crate may
   depend (normal or build dependency, from `cargo metadata`) only on workspace crates of a
   lower layer: never on one of its own layer (so no node crate on another) or above.
2. **Modules.** Within a crate, no import cycle between sibling modules: for every module,
   the graph of its child modules (an edge A -> B when code in A's subtree names a path
   into B's, by `crate::`, `super::`, `self::` or a sibling's name in a `use`) has no cycle.
   A module naming its own descendants or ancestors is not an edge (a parent declares its
   children). `#[cfg(test)]` modules are not production code and are left out.

3. **Sizes.** A library crate holds at most 8,000 production lines, a binary's `main.rs`
   at most 200, a function at most 120 (lines of the source with `#[cfg(test)]` modules
   left out; a function from its `fn` to its closing brace).

A violation still to be taken apart may be listed in `tools/layering-known.txt`, one per
line: `crate: a b c` (a cycle, its modules sorted), `crate -> crate` (a dependency) or
`size: ...` (as the check names it). The
check fails on one not listed and on a listed one that no longer exists, so the list only
shrinks.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ROOT / "tools" / "layers.toml"
KNOWN = ROOT / "tools" / "layering-known.txt"

IDENT = r"[A-Za-z_][A-Za-z0-9_]*"


RAW_STRING = re.compile(r'b?r(#*)"')
CHAR = re.compile(r"'(\\.|\\u\{[0-9a-fA-F]+\}|[^\\'])'")


def strip_code(text: str) -> str:
    """The source without comments, string and char literals (kept as empty ones), line
    for line: the newlines inside what is removed stay, so line numbers hold."""
    out: list[str] = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        start = i
        if text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            depth, i = 1, i + 2
            while i < n and depth:
                if text.startswith("/*", i):
                    depth, i = depth + 1, i + 2
                elif text.startswith("*/", i):
                    depth, i = depth - 1, i + 2
                else:
                    i += 1
            out.append("\n" * text.count("\n", start, i))
        elif (c == "r" or c == "b") and (m := RAW_STRING.match(text, i)):
            close = '"' + m.group(1)
            j = text.find(close, m.end())
            i = n if j < 0 else j + len(close)
            out.append('""' + "\n" * text.count("\n", start, i))
        elif c == '"' or text.startswith('b"', i):
            i += 2 if c == "b" else 1
            while i < n and text[i] != '"':
                i += 2 if text[i] == "\\" else 1
            i += 1
            out.append('""' + "\n" * text.count("\n", start, i))
        elif c == "'" and (m := CHAR.match(text, i)):
            out.append("' '")
            i = m.end()
        else:
            out.append(c)
            i += 1
    return "".join(out)


def drop_test_modules(code: str) -> str:
    """`code` without `#[cfg(test)] mod name { ... }` blocks."""
    while m := re.search(r"#\[cfg\(test\)\]\s*(pub(\([^)]*\))?\s+)?mod\s+" + IDENT + r"\s*\{", code):
        depth, i = 1, m.end()
        while i < len(code) and depth:
            depth += {"{": 1, "}": -1}.get(code[i], 0)
            i += 1
        code = code[: m.start()] + "\n" * code.count("\n", m.start(), i) + code[i:]
    return code


class Module:
    def __init__(self, path: tuple[str, ...], file: Path | None, code: str):
        self.path = path
        self.file = file
        self.code = code
        self.children: dict[str, Module] = {}


def inline_modules(code: str) -> list[tuple[str, str, int, int]]:
    """Top-level inline `mod name { ... }` blocks of `code`: name, body, start, end."""
    found = []
    for m in re.finditer(r"(?m)^\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+(" + IDENT + r")\s*\{", code):
        depth, i = 1, m.end()
        while i < len(code) and depth:
            depth += {"{": 1, "}": -1}.get(code[i], 0)
            i += 1
        found.append((m.group(1), code[m.end() : i - 1], m.start(), i))
    # Keep only the outermost.
    outer = []
    for f in found:
        if not any(o[2] < f[2] and f[3] <= o[3] for o in found):
            outer.append(f)
    return outer


def load_module(path: tuple[str, ...], file: Path, mod_rs: bool, errors: list[str]) -> Module:
    code = drop_test_modules(strip_code(file.read_text()))
    return build_module(path, file, code, file.parent if mod_rs else file.with_suffix(""), errors)


def build_module(path: tuple[str, ...], file: Path, code: str, dir_: Path, errors: list[str]) -> Module:
    inline = inline_modules(code)
    own = code
    for _, _, s, e in sorted(inline, key=lambda f: -f[2]):
        own = own[:s] + own[e:]
    module = Module(path, file, own)
    for name, body, _, _ in inline:
        module.children[name] = build_module(path + (name,), file, body, dir_ / name, errors)
    raw = file.read_text()
    for m in re.finditer(r"(?:pub(?:\([^)]*\))?\s+)?\bmod\s+(" + IDENT + r")\s*;", own):
        name = m.group(1)
        attrs = re.search(
            r"((?:#\[[^\]]*\]\s*)*)(?:pub(?:\([^)]*\))?\s+)?mod\s+" + name + r"\s*;", raw
        )
        attr_text = attrs.group(1) if attrs else ""
        if "cfg(test)" in attr_text:
            continue
        given = re.search(r'#\[path\s*=\s*"([^"]+)"\]', attr_text)
        if given:
            # A `#[path]` module's children are found as a mod.rs file's are.
            candidates = [(file.parent / given.group(1), True)]
        else:
            candidates = [(dir_ / f"{name}.rs", False), (dir_ / name / "mod.rs", True)]
        for c, mod_rs in candidates:
            if c.exists():
                module.children[name] = load_module(path + (name,), c, mod_rs, errors)
                break
        else:
            errors.append(f"{file}: module {name}: no file found")
    return module


def all_modules(m: Module):
    yield m
    for c in m.children.values():
        yield from all_modules(c)


def resolve(root: Module, path: list[str]) -> tuple[str, ...]:
    """The deepest module `path` (from the crate root) names."""
    node, out = root, []
    for seg in path:
        if seg in node.children:
            node = node.children[seg]
            out.append(seg)
        else:
            break
    return tuple(out)


def use_paths(code: str) -> list[list[str]]:
    """Every path a `use` declaration names, braces expanded."""
    paths = []
    for m in re.finditer(r"\buse\s+([^;]+);", code):
        tree = re.sub(r"\s+", "", re.sub(r"\s+as\s+" + IDENT, "", m.group(1)))
        paths.extend(expand(tree))
    return paths


def expand(tree: str) -> list[list[str]]:
    if "{" not in tree:
        return [[s for s in tree.split("::") if s and " as " not in s]]
    i = tree.index("{")
    prefix = [s for s in tree[:i].split("::") if s]
    inner = tree[i + 1 : tree.rindex("}")]
    parts, depth, cur = [], 0, ""
    for ch in inner:
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
            continue
        depth += {"{": 1, "}": -1}.get(ch, 0)
        cur += ch
    parts.append(cur)
    out = []
    for p in parts:
        if p:
            for sub in expand(p):
                out.append(prefix + sub)
    return out


def references(root: Module, m: Module) -> set[tuple[str, ...]]:
    """The modules `m`'s own code names."""
    found: set[tuple[str, ...]] = set()

    def add(path: list[str]) -> None:
        if not path:
            return
        head = path[0]
        if head == "crate":
            found.add(resolve(root, path[1:]))
        elif head in ("super", "self"):
            base = list(m.path)
            rest = path
            while rest and rest[0] in ("super", "self"):
                if rest[0] == "super":
                    base = base[:-1]
                rest = rest[1:]
            found.add(resolve(root, base + rest))
        elif head in m.children:
            found.add(resolve(root, list(m.path) + path))

    for p in use_paths(m.code):
        add(p)
    for hit in re.finditer(r"\b((?:crate|super|self)(?:::" + IDENT + r")+)", m.code):
        add(hit.group(1).split("::"))
    return found


def sibling_edges(root: Module) -> dict[tuple[str, ...], set[tuple[str, str]]]:
    """For each module with children: edges between its children."""
    edges: dict[tuple[str, ...], set[tuple[str, str]]] = {}
    for m in all_modules(root):
        for target in references(root, m):
            src, dst = m.path, target
            k = 0
            while k < min(len(src), len(dst)) and src[k] == dst[k]:
                k += 1
            if k == len(src) or k == len(dst):
                continue  # an ancestor or a descendant
            edges.setdefault(src[:k], set()).add((src[k], dst[k]))
    return edges


def cycles(nodes: set[str], edges: set[tuple[str, str]]) -> list[list[str]]:
    """Strongly connected components of more than one node (Tarjan)."""
    graph: dict[str, list[str]] = {n: [] for n in nodes}
    for a, b in edges:
        graph.setdefault(a, []).append(b)
        graph.setdefault(b, [])
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


CRATE_LINES = 8000
MAIN_LINES = 200
FN_LINES = 120
FN = re.compile(r"\bfn\s+(" + IDENT + r")")


def production(file: Path) -> str:
    """A file's code without comments, literals' contents and test modules, line for line."""
    return drop_test_modules(strip_code(file.read_text()))


def production_lines(file: Path) -> int:
    """A file's lines, its `#[cfg(test)]` modules' left out (comments and blank lines count)."""
    code = strip_code(file.read_text())
    without = drop_test_modules(code)
    # The test modules' lines are blank in `without` and not in `code`.
    tests = sum(
        1 for a, b in zip(code.split("\n"), without.split("\n"), strict=True) if a.strip() and not b.strip()
    )
    blank_in_tests = test_module_blank_lines(code)
    return code.count("\n") - tests - blank_in_tests


def test_module_blank_lines(code: str) -> int:
    """Blank lines inside `code`'s `#[cfg(test)]` modules."""
    n = 0
    for m in re.finditer(r"#\[cfg\(test\)\]\s*(pub(\([^)]*\))?\s+)?mod\s+" + IDENT + r"\s*\{", code):
        depth, i = 1, m.end()
        while i < len(code) and depth:
            depth += {"{": 1, "}": -1}.get(code[i], 0)
            i += 1
        n += sum(1 for line in code[m.start() : i].split("\n") if not line.strip())
    return n


def long_functions(code: str) -> list[tuple[str, int, int]]:
    """(name, first line, lines) of every function body in `code` over [`FN_LINES`]."""
    out = []
    for m in FN.finditer(code):
        i, depth = m.end(), 0
        # The body's brace: the first `{` outside the signature's parentheses, brackets
        # and generics (a `;` first is a declaration without a body).
        while i < len(code):
            ch = code[i]
            if ch in "([<":
                depth += 1
            elif ch in ")]>" and depth:
                depth -= 1
            elif ch == "-" and code.startswith("->", i):
                i += 2
                continue
            elif depth == 0 and ch in "{;":
                break
            i += 1
        if i >= len(code) or code[i] == ";":
            continue
        start, level = i, 0
        while i < len(code):
            level += {"{": 1, "}": -1}.get(code[i], 0)
            if level == 0:
                break
            i += 1
        first = code.count("\n", 0, m.start()) + 1
        lines = code.count("\n", m.start(), i) + 1
        if lines > FN_LINES:
            out.append((m.group(1), first, lines))
    return out


def module_files(m: Module) -> set[Path]:
    files = {m.file} if m.file else set()
    for c in m.children.values():
        files |= module_files(c)
    return files


def sizes(crate: str, kind: str, root: Module, src: Path) -> dict[str, str]:
    """What breaks the size rules in one target: key -> message."""
    out: dict[str, str] = {}
    files = sorted(module_files(root))
    total = 0
    for f in files:
        code = production(f)
        total += production_lines(f)
        rel = f.relative_to(ROOT)
        seen: dict[str, int] = {}
        for name, first, lines in long_functions(code):
            seen[name] = seen.get(name, 0) + 1
            key = f"size: fn {rel} {name}" + (f" ({seen[name]})" if seen[name] > 1 else "")
            out[key] = f"{key}: {lines} lines from line {first} (at most {FN_LINES})"
    if kind == "lib" and total > CRATE_LINES:
        key = f"size: crate {crate}"
        out[key] = f"{key}: {total} production lines (at most {CRATE_LINES})"
    if kind == "bin" and src.name == "main.rs":
        n = production_lines(src)
        if n > MAIN_LINES:
            key = f"size: {src.relative_to(ROOT)}"
            out[key] = f"{key}: {n} production lines (at most {MAIN_LINES})"
    return out


def crate_roots(meta: dict) -> list[tuple[str, Path]]:
    roots = []
    for p in meta["packages"]:
        for t in p["targets"]:
            if set(t["kind"]) & {"lib", "bin", "proc-macro"}:
                roots.append((f"{p['name']} ({t['name']}, {t['kind'][0]})", Path(t["src_path"])))
    return roots


def main() -> int:
    show = "--graph" in sys.argv
    meta = json.loads(
        subprocess.run(
            ["cargo", "metadata", "--format-version", "1", "--no-deps", "--offline"],
            cwd=ROOT,
            check=True,
            capture_output=True,
            text=True,
        ).stdout
    )
    problems: list[str] = []
    # What breaks a rule: a crate dependency `a -> b` or a cycle `crate: m n ...`.
    found: set[str] = set()
    why: dict[str, str] = {}

    # 1. Crates against the declared layers.
    layers = tomllib.loads(LAYERS.read_text())["layers"]
    layer_of = {c: i for i, layer in enumerate(layers) for c in layer["crates"]}
    names = {p["name"] for p in meta["packages"]}
    for name in sorted(names - set(layer_of)):
        problems.append(f"crate {name}: in no layer of {LAYERS.relative_to(ROOT)}")
    for p in meta["packages"]:
        for d in p["dependencies"]:
            if d["name"] not in names or d["kind"] == "dev":
                continue
            a, b = layer_of.get(p["name"]), layer_of.get(d["name"])
            if a is not None and b is not None and b >= a:
                found.add(f"{p['name']} -> {d['name']}")
                where = "its own layer" if a == b else "a layer above"
                why[f"{p['name']} -> {d['name']}"] = (
                    f"crate {p['name']} (layer {layers[a]['name']}) depends on {d['name']} "
                    f"({where}: {layers[b]['name']})"
                )

    # 2. Module cycles within each crate.
    for label, src in crate_roots(meta):
        errors: list[str] = []
        root = load_module((), src, True, errors)
        problems.extend(errors)
        crate = label.split(" ")[0]
        kind = label.rsplit(", ", 1)[1].rstrip(")")
        for key, message in sizes(crate, kind, root, src).items():
            found.add(key)
            why[key] = message
        for parent, edges in sorted(sibling_edges(root).items()):
            node = root
            for seg in parent:
                node = node.children[seg]
            if show:
                for a, b in sorted(edges):
                    print(f"{label}: {'::'.join(parent + (a,))} -> {'::'.join(parent + (b,))}")
            for comp in cycles(set(node.children), edges):
                names_ = " ".join("::".join(parent + (c,)) for c in comp)
                found.add(f"{crate}: {names_}")
                why[f"{crate}: {names_}"] = f"import cycle: {crate}: {names_}"

    known = set()
    if KNOWN.exists():
        for line in KNOWN.read_text().splitlines():
            line = line.split("#")[0].strip()
            if line:
                known.add(" ".join(line.split()))
    for c in sorted(found - known):
        problems.append(why[c])
    for c in sorted(known - found):
        problems.append(f"{KNOWN.relative_to(ROOT)} lists what is gone (remove the line): {c}")

    for p in problems:
        print(p)
    listed = len(found & known)
    print(
        f"layering: {len(layers)} layers, {len(names)} crates; "
        f"{len(found)} violations ({listed} of them listed as known); {len(problems)} problems"
    )
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
