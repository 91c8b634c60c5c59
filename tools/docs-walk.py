#!/usr/bin/env python3
"""A new user's walk through the docs, every command in them run (issue 42's acceptance).

The commands of README.md, docs/payload-guide.md, python/README.md, docs/scenarios.md and
docs/campaigns.md (the shell blocks, line by line, and every inline `m6p-twin ...`, `cargo
...`, `pip ...` span) must each have a step in tools/docs-walk.toml, which says how the walk
runs it: as written (the default), with a stated stand-in for a placeholder such as FILE, in
the background until the doc's walk ends, or where CI runs it already (a test, a section of
.ci/run). A command without a step, or a step whose command is no longer in its doc, fails
the walk before anything runs: docs commands cannot drift.

The walk copies the working tree's files (`git ls-files`) to target/docs-walk/m6p-twin, as a
fresh clone would have them, and runs the docs in order there with `m6p-twin` put on PATH
by the README's own `cargo install` (CARGO_INSTALL_ROOT inside the walk's folder), `pip`
and `pytest` from a virtual environment of its own, and the builds in a target folder of
its own (target/docs-walk-target). A step fails when its exit status is not the one
expected, when its output lacks a text the step names, or when it prints a FAIL the step
did not ask for.
A background program's hints (`(try: m6p-twin ...)`) are followed as steps of their own.

    python3 tools/docs-walk.py          # check the manifest, then walk (a release build)
    python3 tools/docs-walk.py --list   # the commands found, each with its step; no walk
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MANIFEST = ROOT / "tools" / "docs-walk.toml"
DOCS = [
    "README.md",
    "docs/payload-guide.md",
    "python/README.md",
    "docs/scenarios.md",
    "docs/campaigns.md",
    "docs/snapshots.md",
    "docs/control.md",
    "docs/operations.md",
]
SHELL_BLOCKS = {"sh", "bash", "shell", "console"}
COMMAND_WORDS = ("m6p-twin", "cargo", "pip", "pytest", "python3", "nc", "sbatch", "mypy", "ruff", "gs")
INLINE = re.compile(r"(?<!`)`([^`\n]+)`(?!`)")
HINT = re.compile(r"\(try: ((?:m6p-twin|nc) [^,)]*)")
FAIL = re.compile(r"\bFAIL\b")


@dataclass
class Found:
    doc: str
    line: int
    text: str


def strip_comment(line: str) -> str:
    """A shell line without its trailing `# comment` (a `#` outside quotes after a blank)."""
    quote = None
    for i, c in enumerate(line):
        if quote:
            if c == quote:
                quote = None
        elif c in "'\"":
            quote = c
        elif c == "#" and (i == 0 or line[i - 1] in " \t"):
            return line[:i].rstrip()
    return line.rstrip()


def commands_in(doc: str) -> list[Found]:
    """Every command of a doc: shell blocks line by line (a `#!` block is one script), and
    inline code spans that start with a command word. The first place of each text."""
    out: list[Found] = []
    seen: set[str] = set()

    def add(line: int, text: str) -> None:
        if text and text not in seen:
            seen.add(text)
            out.append(Found(doc, line, text))

    lines = (ROOT / doc).read_text().splitlines()
    i = 0
    while i < len(lines):
        fence = re.match(r"^(\s*)```(\w*)", lines[i])
        if fence:
            start, lang = i, fence.group(2)
            i += 1
            body: list[tuple[int, str]] = []
            while i < len(lines) and not re.match(r"^\s*```\s*$", lines[i]):
                body.append((i + 1, lines[i].strip()))
                i += 1
            i += 1
            if lang not in SHELL_BLOCKS:
                continue
            if body and body[0][1].startswith("#!"):
                add(start + 2, "\n".join(t for _, t in body))
                continue
            pending, at = "", 0
            for n, t in body:
                t = strip_comment(t)
                if not pending:
                    at = n
                if t.endswith("\\"):
                    pending += t[:-1].rstrip() + " "
                    continue
                add(at, (pending + t).strip())
                pending = ""
            continue
        for m in INLINE.finditer(lines[i]):
            text = m.group(1).strip()
            if text.split(" ")[0] in COMMAND_WORDS and " " in text or text in ("mypy",):
                add(i + 1, text)
        i += 1
    return out



@dataclass
class Step:
    """One step of the walk (tools/docs-walk.toml)."""

    doc: str
    run: str  # the shell command run ({walk}: the walk's folder; {cmd}: the doc's text)
    cmd: str | None = None  # the doc's text this step runs; None for a step of the walk's own
    exit: int | None = 0  # None: any status
    has: list[str] = field(default_factory=list)
    fails: str | None = None  # why a FAIL is what the user asked for here
    background: str | None = None  # a text that says the program is ready
    stop_exit: int | None = 1
    stop_has: list[str] = field(default_factory=list)
    stdin: str | None = None
    wait_s: float = 0.0
    timeout_s: float = 600.0
    covered: str | None = None  # where CI runs it instead: "FILE" or "FILE: TEXT"


def load_steps() -> tuple[list[Step], dict[str, dict[str, str]]]:
    data = tomllib.loads(MANIFEST.read_text())
    steps: list[Step] = []
    envs: dict[str, dict[str, str]] = {}
    for d in data["doc"]:
        envs[d["file"]] = d.get("env", {})
        for s in d.get("step", []):
            known = set(Step.__dataclass_fields__) - {"doc"}
            unknown = set(s) - known
            if unknown:
                raise SystemExit(f"{MANIFEST.name}: {d['file']}: unknown key(s) {sorted(unknown)} in {s}")
            cmd = s.get("cmd")
            run = s.get("run", cmd)
            if run is None and not s.get("covered"):
                raise SystemExit(f"{MANIFEST.name}: {d['file']}: a step needs `cmd`, `run` or `covered`: {s}")
            step = Step(doc=d["file"], **{**s, "run": run or ""})
            if step.exit == -1:
                step.exit = None
            steps.append(step)
    return steps, envs


def check_manifest(steps: list[Step], verbose: bool) -> list[str]:
    """Every command of the docs has a step, and every step's command is in its doc."""
    problems: list[str] = []
    for doc in DOCS:
        found = commands_in(doc)
        mine = {s.cmd for s in steps if s.doc == doc and s.cmd is not None}
        texts = {f.text for f in found}
        for f in found:
            how = next((s for s in steps if s.doc == doc and s.cmd == f.text), None)
            if how is None:
                problems.append(f"{doc}:{f.line}: no step in {MANIFEST.name} runs `{f.text}`")
            elif verbose:
                way = f"covered by {how.covered}" if how.covered else (
                    "as written" if how.run == f.text else f"as `{how.run}`")
                print(f"{doc}:{f.line}: `{f.text}`: {way}")
        for cmd in sorted(mine - texts):
            problems.append(f"{MANIFEST.name}: {doc}: `{cmd}` is no longer in the doc")
    for s in steps:
        if s.covered:
            path, _, text = s.covered.partition(": ")
            f = ROOT / path
            if not f.is_file():
                problems.append(f"{MANIFEST.name}: {s.doc}: `{s.cmd}` covered by {path}, which does not exist")
            elif text and text not in f.read_text():
                problems.append(f"{MANIFEST.name}: {s.doc}: `{s.cmd}` covered by {path}, which lacks `{text}`")
    return problems


class Walk:
    def __init__(self, walk: Path, env: dict[str, str]) -> None:
        self.walk = walk
        self.work = walk / "m6p-twin"
        self.env = env
        self.background: list[tuple[Step, subprocess.Popen[bytes], Path]] = []
        self.failed: list[str] = []
        self.ran = 0
        self.hints_followed: set[str] = set()

    def fill(self, text: str) -> str:
        return text.replace("{walk}", str(self.walk))

    def command(self, s: Step) -> str:
        return self.fill(s.run).replace("{cmd}", s.cmd or "")

    def report(self, ok: bool, what: str, secs: float, out: str = "", why: str = "") -> None:
        self.ran += 1
        print(f"{'ok  ' if ok else 'FAIL'} {what} ({secs:.1f} s){'' if ok else ': ' + why}", flush=True)
        if not ok:
            self.failed.append(f"{what}: {why}")
            tail = "\n".join(out.splitlines()[-25:])
            print("     | " + tail.replace("\n", "\n     | "), flush=True)

    def judge(self, s: Step, code: int | None, out: str, expect: int | None, has: list[str]) -> str:
        if expect is not None and code != expect:
            return f"exit status {code}, expected {expect}"
        for h in has:
            if h not in out:
                return f"the output lacks `{h}`"
        if s.fails is None and FAIL.search(out):
            line = next(ln for ln in out.splitlines() if FAIL.search(ln))
            return f"a FAIL nobody asked for: {line.strip()}"
        return ""

    def step(self, s: Step, env: dict[str, str]) -> None:
        what = f"{s.doc}: {s.cmd or '(walk) ' + s.run}".replace("\n", " / ")
        if s.covered:
            print(f"ok   {what} (run by {s.covered.partition(': ')[0]})", flush=True)
            return
        if s.wait_s:
            time.sleep(s.wait_s)
        run = self.command(s)
        t0 = time.monotonic()
        if s.background:
            log = self.walk / f"background-{len(self.background)}.log"
            f = open(log, "wb")
            p = subprocess.Popen(["bash", "-c", run], cwd=self.work, env=env, stdout=f,
                                 stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
            self.background.append((s, p, log))
            while time.monotonic() - t0 < s.timeout_s:
                text = log.read_text(errors="replace")
                if s.background in text:
                    self.report(True, what + " (started)", time.monotonic() - t0)
                    self.follow_hints(text, env)
                    return
                if p.poll() is not None:
                    break
                time.sleep(0.2)
            self.report(False, what, time.monotonic() - t0, log.read_text(errors="replace"),
                        f"never printed `{s.background}`")
            return
        try:
            r = subprocess.run(["bash", "-c", run], cwd=self.work, env=env, capture_output=True,
                               input=(s.stdin or "").encode(), timeout=s.timeout_s)
            code, out = r.returncode, (r.stdout + r.stderr).decode(errors="replace")
        except subprocess.TimeoutExpired as e:
            code, out = None, ((e.stdout or b"") + (e.stderr or b"")).decode(errors="replace")
            if s.exit is not None:
                self.report(False, what, time.monotonic() - t0, out, f"still running after {s.timeout_s} s")
                return
        why = self.judge(s, code, out, s.exit, s.has)
        self.report(not why, what, time.monotonic() - t0, out, why)

    def follow_hints(self, text: str, env: dict[str, str]) -> None:
        """A hint the twin prints must work when followed."""
        for hint in HINT.findall(text):
            if hint in self.hints_followed:
                continue
            self.hints_followed.add(hint)
            t0 = time.monotonic()
            if hint.startswith("nc "):
                # A console: `help` typed, its answer read for 3 s (nc waits for more).
                r = subprocess.run(["bash", "-c", f"timeout 3 {hint}"], cwd=self.work, env=env,
                                   capture_output=True, input=b"help\n", timeout=60)
                out = (r.stdout + r.stderr).decode(errors="replace")
                why = "" if r.returncode in (0, 124) and r.stdout.strip() else f"exit status {r.returncode}, no answer"
            else:
                r = subprocess.run(["bash", "-c", hint], cwd=self.work, env=env, capture_output=True, timeout=60)
                out = (r.stdout + r.stderr).decode(errors="replace")
                why = f"exit status {r.returncode}" if r.returncode != 0 else ""
            self.report(not why, f"(hint) {hint}", time.monotonic() - t0, out, why)

    def stop_background(self) -> None:
        for s, p, log in reversed(self.background):
            t0 = time.monotonic()
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
            out = log.read_text(errors="replace")
            what = f"{s.doc}: {s.cmd or s.run} (stopped with SIGINT)"
            why = self.judge(s, p.returncode, out, s.stop_exit, s.stop_has)
            self.report(not why, what, time.monotonic() - t0, out, why)
        self.background.clear()


def prepare(walk: Path) -> dict[str, str]:
    """The walk's folder: the checkout's files as a fresh clone has them, a virtual
    environment for pip, an install root for cargo install."""
    if walk.exists():
        shutil.rmtree(walk)
    work = walk / "m6p-twin"
    files = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                           cwd=ROOT, capture_output=True, check=True).stdout.split(b"\0")
    for name in files:
        if not name:
            continue
        src = ROOT / name.decode()
        if src.is_file():
            dst = work / name.decode()
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst)
    # Not the system's packages: `pytest` must be the one `pip install` put beside the package.
    subprocess.run([sys.executable, "-m", "venv", str(walk / "venv")], check=True)
    env = dict(os.environ)
    env["PATH"] = f"{walk / 'cargo-root' / 'bin'}:{walk / 'venv' / 'bin'}:{env['PATH']}"
    env["VIRTUAL_ENV"] = str(walk / "venv")
    env["CARGO_INSTALL_ROOT"] = str(walk / "cargo-root")
    # A target folder of the walk's own: builds of a copy of the workspace in the checkout's
    # target/ share the binary's fingerprint with the checkout's, whose release build then
    # looks fresh when it is not. Kept between walks (outside the folder removed above).
    env["CARGO_TARGET_DIR"] = str(ROOT / "target" / "docs-walk-target")
    env["M6P_GS_HISTORY"] = str(walk / "gs-history")
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    # The README's `pip install mypy ruff` takes the versions .ci/run pins.
    env["PIP_CONSTRAINT"] = str(ROOT / "tools" / "python-tools.txt")
    for k in ("M6P_TWIN", "RUST_LOG", "SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX"):
        env.pop(k, None)
    return env


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--list", action="store_true", help="list the docs' commands and their steps; no walk")
    ap.add_argument("--doc", action="append", help="walk only this doc (repeatable; the manifest is checked whole)")
    args = ap.parse_args()
    steps, envs = load_steps()
    problems = check_manifest(steps, args.list)
    for p in problems:
        print(p)
    if problems:
        print(f"{len(problems)} problem(s): every command of the docs needs a step in {MANIFEST.relative_to(ROOT)}")
        return 1
    if args.list:
        return 0
    walk = ROOT / "target" / "docs-walk"
    env = prepare(walk)
    w = Walk(walk, env)
    t_all = time.monotonic()
    for doc in DOCS:
        if args.doc and doc not in args.doc:
            continue
        t0 = time.monotonic()
        print(f"\n== {doc}", flush=True)
        denv = {**env, **{k: w.fill(v) for k, v in envs.get(doc, {}).items()}}
        try:
            for s in (s for s in steps if s.doc == doc):
                w.step(s, denv)
        finally:
            w.stop_background()
        print(f"== {doc}: {time.monotonic() - t0:.0f} s", flush=True)
    print(f"\ndocs walk: {w.ran} steps, {len(w.failed)} failed, {len(w.hints_followed)} hint(s) followed, "
          f"in {time.monotonic() - t_all:.0f} s")
    for f in w.failed:
        print(f"  FAIL {f}")
    return 1 if w.failed else 0


if __name__ == "__main__":
    sys.exit(main())
