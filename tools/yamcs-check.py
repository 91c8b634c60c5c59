#!/usr/bin/env python3
"""The real YAMCS against a running twin (examples/yamcs, docs/operations.md): a CI section.

    python3 tools/yamcs-check.py [TWIN_BIN] [--screenshots DIR]

TWIN_BIN is the m6p-twin binary (else $M6P_TWIN_BIN, else target/release/m6p-twin). The
check starts the twin on the default scenario in real time with the UDP link the example
expects (`run --realtime --udp 127.0.0.1:10015,127.0.0.1:10016`), starts YAMCS with
`mvn -B yamcs:run` in examples/yamcs (its archive in a temporary folder; Maven's downloads
stay in ~/.m2), waits for the instance to be RUNNING, then through the REST API:

- sends FC TMGEN, EPS TMEPS and PC SETUP (session 1, start now) and reads back the decoded
  telemetry: TMGEN uptime_s and current_mode, TMEPS battery_v, the PC's success reply;
- asserts each one's generationTime is the twin's simulated UTC, the scenario's start plus
  the real time since the twin started, within TOLERANCE_S (the FC's RTC counts whole
  seconds; the clock between timed packets runs on YAMCS's side), and so is YAMCS's
  mission time before any command (the link's TWINSIM requests);
- asserts each command's history says Acknowledge_Sent OK, TMGEN's binary is the CSP
  request from YAMCS's address 17 port 40, and the twin counted the datagrams.

Then it stops the twin with SIGINT (its report, "interrupted at") and YAMCS with SIGTERM to
its process group. Any failure exits 1 with the reason and the logs' tails. --screenshots DIR
also saves PNGs of YAMCS's web UI (headless Chromium through tools/yamcs-check/shots.mjs;
`npm ci` there first when node_modules is missing). Python 3 standard library only.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import tomllib
import urllib.error
import urllib.request
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "yamcs"
SCENARIO = ROOT / "scenarios" / "default.toml"
SHOTS = ROOT / "tools" / "yamcs-check"
API = "http://127.0.0.1:8090/api"
TWIN_UDP, YAMCS_UDP, HTTP_PORT = 10015, 10016, 8090
TOLERANCE_S = 2.0
YAMCS_START_TIMEOUT_S = 900.0  # a cold ~/.m2 downloads about 80 MB first
REPLY_TIMEOUT_S = 15.0


class CheckFailed(Exception):
    pass


def log(msg: str) -> None:
    print(f"[yamcs-check {time.strftime('%H:%M:%S')}] {msg}", flush=True)


def api(method: str, path: str, body: dict[str, Any] | None = None, timeout: float = 10.0) -> Any:
    data = json.dumps(body).encode() if body is not None else None
    req = urllib.request.Request(API + path, data=data, method=method)
    if data is not None:
        req.add_header("Content-Type", "application/json")
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return json.loads(r.read() or b"{}")
    except urllib.error.HTTPError as e:
        raise CheckFailed(
            f"{method} {path}: HTTP {e.code} {e.read().decode(errors='replace')}"
        ) from e


def parse_time(s: str) -> float:
    """RFC 3339 (YAMCS's JSON timestamps) to unix seconds."""
    return datetime.fromisoformat(s).timestamp()


def iso(t: float) -> str:
    return datetime.fromtimestamp(t, UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def port_free(port: int, kind: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as s:
        if kind == socket.SOCK_STREAM:
            s.setsockopt(
                socket.SOL_SOCKET, socket.SO_REUSEADDR, 1
            )  # as servers do: TIME_WAIT is no user
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def tail(path: Path, n: int = 40) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    except OSError:
        return "(no log)"


class Check:
    def __init__(self, twin_bin: Path, workdir: Path) -> None:
        self.twin_bin = twin_bin
        self.workdir = workdir
        self.twin_log = workdir / "twin.log"
        self.yamcs_log = workdir / "yamcs.log"
        self.twin: subprocess.Popen[bytes] | None = None
        self.yamcs: subprocess.Popen[bytes] | None = None
        self.twin_t0 = 0.0  # wall time of the twin's simulated time zero
        start = tomllib.loads(SCENARIO.read_text())["start"]
        self.start_unix = parse_time(start if isinstance(start, str) else start.isoformat())
        self.timings: dict[str, float] = {}

    def sim_now(self) -> float:
        """The twin's simulated UTC now (unix s): its real-time run is at speed 1."""
        return self.start_unix + (time.time() - self.twin_t0)

    def assert_sim_time(self, what: str, gen: str, expected: float) -> None:
        d = parse_time(gen) - expected
        if abs(d) > TOLERANCE_S:
            raise CheckFailed(
                f"{what}: generationTime {gen} is {d:+.3f} s from the simulated time "
                f"{iso(expected)} (tolerance {TOLERANCE_S} s)"
            )
        log(f"  {what}: generationTime {gen} (simulated time {iso(expected)}, {d:+.3f} s)")

    # ---- processes

    def start_twin(self) -> None:
        cmd = [
            str(self.twin_bin),
            "run",
            "--realtime",
            "--udp",
            f"127.0.0.1:{TWIN_UDP},127.0.0.1:{YAMCS_UDP}",
        ]
        log("twin: " + " ".join(cmd))
        out = self.twin_log.open("wb")
        self.twin = subprocess.Popen(
            cmd,
            stdout=out,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )
        deadline = time.time() + 30
        while time.time() < deadline:
            text = self.twin_log.read_text(errors="replace")
            if "CSP/UDP: on" in text:
                self.twin_t0 = time.time()  # refined by refine_t0()
                return
            if self.twin.poll() is not None:
                raise CheckFailed(
                    f"the twin exited ({self.twin.returncode}) before opening its UDP link"
                )
            time.sleep(0.02)
        raise CheckFailed("the twin did not print `CSP/UDP: on` within 30 s")

    def start_yamcs(self) -> None:
        # The archive in the work folder: every run of the default scenario has the same
        # simulated times, and another run's packets must not answer for this one's.
        cmd = ["mvn", "-B", "yamcs:run", f"-Dyamcs.directory={self.workdir / 'yamcs'}"]
        log(f"YAMCS: {' '.join(cmd)} (in {EXAMPLE})")
        out = self.yamcs_log.open("wb")
        t = time.time()
        self.yamcs = subprocess.Popen(
            cmd,
            cwd=EXAMPLE,
            stdout=out,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )
        deadline = t + YAMCS_START_TIMEOUT_S
        while time.time() < deadline:
            if self.yamcs.poll() is not None:
                raise CheckFailed(
                    f"mvn yamcs:run exited ({self.yamcs.returncode}) before the instance ran"
                )
            try:
                if api("GET", "/instances/m6p", timeout=2).get("state") == "RUNNING":
                    self.timings["YAMCS start (mvn yamcs:run to RUNNING)"] = time.time() - t
                    log(f"YAMCS: instance m6p RUNNING after {time.time() - t:.1f} s")
                    return
            except (CheckFailed, OSError):
                pass
            time.sleep(0.5)
        raise CheckFailed(f"instance m6p not RUNNING within {YAMCS_START_TIMEOUT_S:.0f} s")

    def refine_t0(self) -> None:
        """The twin's time zero from its first log line with a simulated time: that line's wall
        clock (`2026-...Z  INFO ... t=0.000000000s`) less its `t=`. The twin's run starts a
        little after it prints `CSP/UDP: on`."""
        m = re.search(
            r"^(\d{4}-\d\d-\d\dT[\d:.]+)Z .* t=(\d+\.\d+)s$",
            self.twin_log.read_text(errors="replace"),
            re.MULTILINE,
        )
        if m:
            wall = datetime.fromisoformat(m.group(1)[:26]).replace(tzinfo=UTC).timestamp()
            t0 = wall - float(m.group(2))
            log(
                f"twin: simulated time zero at wall {iso(t0)} "
                f"({t0 - self.twin_t0:+.3f} s from `CSP/UDP: on`)"
            )
            self.twin_t0 = t0

    def stop_twin(self) -> str:
        assert self.twin is not None
        self.twin.send_signal(signal.SIGINT)
        try:
            rc = self.twin.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(self.twin.pid, signal.SIGKILL)
            raise CheckFailed("the twin did not stop within 20 s of SIGINT") from None
        self.twin = None
        report = self.twin_log.read_text(errors="replace")
        # An interrupted run is "not a result": the twin exits 1 after its report (0 never
        # for SIGINT in this version); a panic or a crash would exit otherwise or say less.
        if rc not in (0, 1) or "interrupted at" not in report:
            raise CheckFailed(
                f"the twin's exit after SIGINT: status {rc}, report:\n{tail(self.twin_log)}"
            )
        log(f"twin: stopped by SIGINT (exit {rc}, `interrupted at` in its report)")
        return report

    def stop_yamcs(self) -> None:
        if self.yamcs is None:
            return
        t = time.time()
        try:
            os.killpg(self.yamcs.pid, signal.SIGTERM)
            self.yamcs.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(self.yamcs.pid, signal.SIGKILL)
            self.yamcs.wait()
        except ProcessLookupError:
            pass
        self.timings["YAMCS stop (SIGTERM to its process group)"] = time.time() - t
        self.yamcs = None

    def cleanup(self) -> None:
        for p in (self.twin, self.yamcs):
            if p is not None and p.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        self.twin = self.yamcs = None

    # ---- the checks

    def wait_link_and_time(self) -> None:
        """The link's TWINSIM requests set YAMCS's mission time before any command."""
        deadline = time.time() + 20
        last: Any = None
        while time.time() < deadline:
            link = next(x for x in api("GET", "/links/m6p")["links"] if x["name"] == "csp-udp")
            inst = api("GET", "/instances/m6p")
            last = (link, inst.get("missionTime"))
            if (
                link["status"] == "OK"
                and int(link.get("dataInCount", "0")) > 0
                and inst.get("missionTime")
            ):
                self.assert_sim_time(
                    "mission time (TWINSIM at the link's start)",
                    inst["missionTime"],
                    self.sim_now(),
                )
                return
            time.sleep(0.5)
        raise CheckFailed(f"link csp-udp got no packet from the twin within 20 s: {last}")

    def command(self, name: str, args: dict[str, Any] | None = None) -> dict[str, Any]:
        r: dict[str, Any] = api(
            "POST", f"/processors/m6p/realtime/commands{name}", {"args": args or {}}
        )
        r["sim_sent"] = self.sim_now()  # the twin's simulated UTC when the command was issued
        log(f"sent {name}: id {r['id']}")
        self.assert_sim_time(f"{name} command", r["generationTime"], r["sim_sent"])
        return r

    def acquired(self, name: str) -> str | None:
        """The acquisitionTime of the parameter's current value (None: none yet)."""
        v = api("GET", f"/processors/m6p/realtime/parameters{name}")
        return v.get("acquisitionTime") if isinstance(v, dict) else None

    def param_after(self, name: str, cmd: dict[str, Any], before: str | None) -> dict[str, Any]:
        """The parameter's first value acquired after `before` (read before the command)."""
        deadline = time.time() + REPLY_TIMEOUT_S
        while time.time() < deadline:
            v: dict[str, Any] = api("GET", f"/processors/m6p/realtime/parameters{name}")
            if v.get("acquisitionTime") not in (None, before):
                return v
            time.sleep(0.2)
        raise CheckFailed(f"no {name} received within {REPLY_TIMEOUT_S} s of {cmd['commandName']}")

    def reply_packet(self, cmd: dict[str, Any], src: int, names: tuple[str, ...]) -> dict[str, Any]:
        """The archived reply to `cmd` from CSP `src` (port 10) to YAMCS (17, port 40), under
        one of `names` (the packet name: its most specific MDB container)."""
        since = parse_time(cmd["generationTime"])
        q = f"?start={iso(since - 5)}&stop={iso(since + 120)}&limit=200"
        deadline = time.time() + REPLY_TIMEOUT_S
        while time.time() < deadline:
            for p in api("GET", "/archive/m6p/packets" + q).get("packets", []):
                b = base64.b64decode(p["packet"])
                h = int.from_bytes(b[:4], "big")
                hdr = ((h >> 25) & 31, (h >> 20) & 31, (h >> 14) & 63, (h >> 8) & 63)
                # this run's own archive (a fresh folder); 2 s: the clock's corrections
                if (
                    hdr == (src, 17, 40, 10)
                    and len(b) >= 6
                    and b[4] == cmd_id(cmd)
                    and parse_time(p["receptionTime"]) >= since - 2
                ):
                    if p["id"]["name"] not in names:
                        raise CheckFailed(
                            f"the reply to {cmd['commandName']} ({b.hex()}) is archived as "
                            f"{p['id']['name']}, not {' or '.join(names)}"
                        )
                    p["bytes"] = b
                    return p  # type: ignore[no-any-return]
            time.sleep(0.3)
        raise CheckFailed(
            f"no reply to {cmd['commandName']} from CSP {src} archived within {REPLY_TIMEOUT_S} s"
        )

    def history(self, cmds: list[dict[str, Any]]) -> None:
        since = min(parse_time(c["generationTime"]) for c in cmds)
        q = f"?start={iso(since - 5)}&stop={iso(since + 600)}&limit=100".replace(":", "%3A")
        deadline = time.time() + REPLY_TIMEOUT_S
        want = {c["id"]: c for c in cmds}
        while True:
            seen = {
                e["id"]: e
                for e in api("GET", "/archive/m6p/commands" + q).get("commands", [])
                if e["id"] in want
            }
            acks = {i: {a["name"]: a["value"] for a in e.get("attr", [])} for i, e in seen.items()}
            ok = [
                i
                for i, a in acks.items()
                if a.get("Acknowledge_Sent_Status", {}).get("stringValue") == "OK"
            ]
            if len(ok) == len(want):
                break
            if time.time() > deadline:
                raise CheckFailed(
                    f"command history: Acknowledge_Sent OK for {len(ok)} of {len(want)} "
                    f"commands: {acks}"
                )
            time.sleep(0.3)
        for i, a in acks.items():
            log(
                f"  history {want[i]['commandName']}: "
                f"Acknowledge_Queued {a['Acknowledge_Queued_Status']['stringValue']}, "
                f"Acknowledge_Released {a['Acknowledge_Released_Status']['stringValue']}, "
                "Acknowledge_Sent OK"
            )
        # With the MDB's verifiers (a Complete verifier on the command's success reply
        # container), the history says the twin answered: CommandComplete OK.
        for c in cmds:
            name = c["commandName"]
            if not api("GET", "/mdb/m6p/commands" + name).get("verifier"):
                log(f"  history {name}: no verifiers in the MDB: completion not checked")
                continue
            while True:
                e = next(
                    x
                    for x in api("GET", "/archive/m6p/commands" + q).get("commands", [])
                    if x["id"] == c["id"]
                )
                a = {x["name"]: x["value"] for x in e.get("attr", [])}
                status = a.get("CommandComplete_Status", {}).get("stringValue")
                if status is not None:
                    break
                if time.time() > deadline:
                    raise CheckFailed(
                        f"{name}: no CommandComplete in its history within "
                        f"{REPLY_TIMEOUT_S} s: {sorted(a)}"
                    )
                time.sleep(0.3)
            if status != "OK" or a.get("Verifier_Complete_Status", {}).get("stringValue") != "OK":
                raise CheckFailed(
                    f"{name}: CommandComplete {status}, "
                    f"Verifier_Complete {a.get('Verifier_Complete_Status')}: "
                    f"{a.get('CommandComplete_Message')}"
                )
            log(
                f"  history {name}: Verifier_Complete OK, CommandComplete OK "
                "(the twin's success reply)"
            )
        tmgen = next(a for i, a in acks.items() if want[i]["commandName"] == "/M6P/FC/TMGEN")
        binary = base64.b64decode(tmgen["binary"]["binaryValue"]).hex()
        # prio 2, src 17, dst 3 (FC), dport 10, sport 40, no flags | command 1
        if binary != "a232a80001":
            raise CheckFailed(f"TMGEN's binary in the command history is {binary}, not a232a80001")
        log(f"  history /M6P/FC/TMGEN: binary {binary} (CSP 17:40 -> 3:10, TMGEN)")

    def run(self, screenshots: Path | None) -> None:
        for port, kind, what in (
            (TWIN_UDP, socket.SOCK_DGRAM, "UDP"),
            (YAMCS_UDP, socket.SOCK_DGRAM, "UDP"),
            (HTTP_PORT, socket.SOCK_STREAM, "TCP"),
        ):
            if not port_free(port, kind):
                raise CheckFailed(f"{what} 127.0.0.1:{port} is in use (another twin or YAMCS?)")
        for tool in ("mvn", "java"):
            if shutil.which(tool) is None:
                raise CheckFailed(f"`{tool}` is not on PATH (the example needs Java 17 and Maven)")
        t_all = time.time()
        self.start_twin()
        self.start_yamcs()
        self.refine_t0()
        self.wait_link_and_time()

        watched = (
            "/M6P/FC/TMGEN/uptime_s",
            "/M6P/FC/TMGEN/current_mode",
            "/M6P/EPS/TMEPS/battery_v",
        )
        before = {n: self.acquired(n) for n in watched}
        tmgen = self.command("/M6P/FC/TMGEN")
        tmeps = self.command("/M6P/EPS/TMEPS")
        setup_args = {
            "session_id": 1,
            "timestamp": 0,
            "duration_s": 60,
            "max_packets": 30,
            "poll_frame_size": 64,
            "sync_message": "676f",
        }
        setup = self.command("/M6P/PC/SETUP", setup_args)

        up = self.param_after("/M6P/FC/TMGEN/uptime_s", tmgen, before["/M6P/FC/TMGEN/uptime_s"])
        mode = self.param_after(
            "/M6P/FC/TMGEN/current_mode", tmgen, before["/M6P/FC/TMGEN/current_mode"]
        )
        uptime = up["engValue"]["uint32Value"]
        if not 0 < uptime <= time.time() - self.twin_t0 + 2:
            raise CheckFailed(
                f"TMGEN uptime_s {uptime} is not within the twin's run "
                f"({time.time() - self.twin_t0:.1f} s)"
            )
        if mode["engValue"]["type"] != "ENUMERATED":
            raise CheckFailed(
                f"TMGEN current_mode is not decoded as an enumeration: {mode['engValue']}"
            )
        log(f"TMGEN: uptime_s {uptime}, current_mode {mode['engValue']['stringValue']!r}")
        self.assert_sim_time("TMGEN uptime_s", up["generationTime"], tmgen["sim_sent"])
        self.reply_packet(tmgen, 3, ("/M6P/FC/TMGEN/reply",))

        bv = self.param_after("/M6P/EPS/TMEPS/battery_v", tmeps, before["/M6P/EPS/TMEPS/battery_v"])
        volts = bv["engValue"]["floatValue"]
        if not 5.0 < volts < 9.0:
            raise CheckFailed(f"TMEPS battery_v {volts} is not a 2S battery's voltage")
        log(f"TMEPS: battery_v {volts:.3f} V")
        self.assert_sim_time("TMEPS battery_v", bv["generationTime"], tmeps["sim_sent"])

        rep = self.reply_packet(setup, 6, ("/M6P/PC/SETUP/reply", "/M6P/reply"))
        if rep["bytes"][4:6] != b"\x01\x01":
            raise CheckFailed(
                f"PC SETUP's reply is {rep['bytes'][4:].hex()}, not the success reply 0101"
            )
        log(
            f"PC SETUP: success reply {rep['bytes'].hex()} from CSP 6 port 10, "
            f"archived as {rep['id']['name']}"
        )
        self.assert_sim_time("PC SETUP reply", rep["generationTime"], setup["sim_sent"])

        self.history([tmgen, tmeps, setup])

        if screenshots is not None:
            self.screenshots(screenshots)

        report = self.stop_twin()
        m = re.search(rf"link udp 127\.0\.0\.1:{TWIN_UDP}: .*?(\d+) packets in, (\d+) out", report)
        if not m or int(m.group(1)) < 4:
            raise CheckFailed(
                "the twin's report has no UDP link line with the commands received: "
                f"{m and m.group(0)}"
            )
        log(f"twin: its UDP link counted {m.group(1)} packets in, {m.group(2)} out")
        self.stop_yamcs()
        self.timings["whole check"] = time.time() - t_all

    def screenshots(self, out: Path) -> None:
        if shutil.which("node") is None:
            raise CheckFailed("--screenshots needs node (and npm) on PATH")
        if not (SHOTS / "node_modules" / "puppeteer-core").is_dir():
            subprocess.run(["npm", "ci", "--no-audit", "--no-fund"], cwd=SHOTS, check=True)
        out.mkdir(parents=True, exist_ok=True)
        r = subprocess.run(
            ["node", str(SHOTS / "shots.mjs"), str(out.resolve())],
            check=False,
            cwd=SHOTS,
            capture_output=True,
            text=True,
            timeout=180,
        )
        sys.stdout.write(r.stdout)
        if r.returncode != 0:
            raise CheckFailed(f"screenshots failed ({r.returncode}):\n{r.stderr[-3000:]}")


def cmd_id(cmd: dict[str, Any]) -> int:
    for a in cmd.get("assignments", []):
        if a["name"] == "command":
            return int(a["value"].get("uint32Value", 0))
    raise CheckFailed(f"{cmd['commandName']}: no `command` assignment in {cmd.get('assignments')}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "twin_bin",
        nargs="?",
        help="the m6p-twin binary (default: $M6P_TWIN_BIN, else target/release/m6p-twin)",
    )
    ap.add_argument(
        "--screenshots", type=Path, metavar="DIR", help="save PNGs of YAMCS's web UI into DIR"
    )
    ap.add_argument(
        "--keep", type=Path, metavar="DIR", help="keep the logs and YAMCS's folder in DIR"
    )
    a = ap.parse_args()
    twin_bin = Path(
        a.twin_bin or os.environ.get("M6P_TWIN_BIN") or ROOT / "target" / "release" / "m6p-twin"
    )
    if not os.access(twin_bin, os.X_OK):
        print(
            f"yamcs-check: FAIL: no twin binary at {twin_bin} (argument or M6P_TWIN_BIN)",
            file=sys.stderr,
        )
        return 1
    workdir = Path(tempfile.mkdtemp(prefix="yamcs-check-")) if a.keep is None else a.keep
    workdir.mkdir(parents=True, exist_ok=True)
    check = Check(twin_bin.resolve(), workdir.resolve())
    t = time.time()
    try:
        check.run(a.screenshots)
    except (CheckFailed, OSError, subprocess.SubprocessError, KeyError, ValueError) as e:
        print(
            f"yamcs-check: FAIL: {'' if isinstance(e, CheckFailed) else type(e).__name__ + ': '}"
            f"{e}",
            file=sys.stderr,
        )
        print(
            f"--- twin log ({check.twin_log}), last lines:\n{tail(check.twin_log)}", file=sys.stderr
        )
        print(
            f"--- YAMCS log ({check.yamcs_log}), last lines:\n{tail(check.yamcs_log)}",
            file=sys.stderr,
        )
        check.cleanup()
        return 1
    finally:
        check.cleanup()
    for k, v in check.timings.items():
        log(f"time: {k}: {v:.1f} s")
    log(f"PASS in {time.time() - t:.1f} s")
    if a.keep is None:
        shutil.rmtree(workdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
