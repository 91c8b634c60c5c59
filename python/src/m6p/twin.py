"""Start and stop a twin from Python (for pytest, notebooks, scripts).

::

    with Twin(seed=7) as twin:                # the embedded default scenario
        ground = twin.ground()               # a CspNode as ground station 17
        print(ground.command("FC.TMGEN"))
    print(twin.returncode, twin.downlink(1))

The twin runs ``m6p-twin run SCENARIO --realtime --forever`` with a KISS/TCP server for
the ground (``ground_addr``, 17) and one for the payload addresses it takes over from the
simulated payloads (``payload_addrs``, default 12), each on a free port of 127.0.0.1, and
records the run to ``workdir/run.mcap`` (the downlinked files go beside it, in
``workdir/run.downlink/``). With ``zmq=True`` the payloads join over libcsp 1.4's ZMQ hub
instead, on a loopback address of its own. :meth:`stop` stops it as Ctrl-C does: the run's
report and recording are complete.
"""

from __future__ import annotations

import os
import random
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, TypedDict

from .icd import Icd
from .links import KissTcp, Link, ZmqHub
from .node import CspNode

if TYPE_CHECKING:
    from typing_extensions import Self  # for the checker only, as in m6p.node

__all__ = ["Twin", "TwinError", "TwinOptions", "find_binary"]

# `KISS/TCP: listening on 127.0.0.1:40123 for CSP 12, 13 (try: ...)`: the twin names each
# listening link's CSP addresses, so that ours are told apart from a scenario's own links.
_LISTENING = re.compile(r"KISS/TCP: listening on (\S+):(\d+)(?: for CSP ([0-9, ]+))?")


class TwinError(RuntimeError):
    """The twin could not start, or stopped before it was ready; the message ends with
    the twin's own words."""


def find_binary() -> str:
    """The ``m6p-twin`` to run: ``$M6P_TWIN``; else ``m6p-twin`` on ``PATH``; else the
    newest of ``target/release/m6p-twin`` and ``target/debug/m6p-twin`` in the current
    directory or one above it."""
    env = os.environ.get("M6P_TWIN")
    if env:
        if not os.access(env, os.X_OK):
            raise TwinError(f"M6P_TWIN={env} is not an executable file")
        return env
    on_path = shutil.which("m6p-twin")
    if on_path:
        return on_path
    found: list[Path] = []
    here = Path.cwd()
    for d in [here, *here.parents]:
        for profile in ("release", "debug"):
            p = d / "target" / profile / "m6p-twin"
            if p.is_file() and os.access(p, os.X_OK):
                found.append(p)
        if found:
            break
    if not found:
        raise TwinError(
            "no m6p-twin found: set M6P_TWIN, put m6p-twin on PATH, or build it "
            "(cargo build --release -p m6p-twin) and run from the repository"
        )
    return str(max(found, key=lambda p: p.stat().st_mtime))


class TwinOptions(TypedDict, total=False):
    """:class:`Twin`'s arguments as a dict (``Twin(**options)``): what the ``twin``
    marker and fixture of :mod:`m6p.pytest_plugin` take."""

    scenario: str | os.PathLike[str] | None
    seed: int | None
    duration: str | None
    speed: float
    payload_addrs: Sequence[int]
    ground_addr: int
    zmq: bool
    record: bool
    binary: str | None
    workdir: str | os.PathLike[str] | None
    args: Iterable[str]
    start_timeout_s: float


class Twin:
    """A twin process.

    ``scenario``: a scenario file, or TOML text (anything with a newline), or None for
    the embedded default scenario. ``seed``, ``duration`` (``"90s"``; default: until
    :meth:`stop`) and ``speed`` (simulated seconds per wall second) as ``m6p-twin run``
    takes them. ``args``: more arguments for ``m6p-twin run``.
    """

    def __init__(
        self,
        scenario: str | os.PathLike[str] | None = None,
        *,
        seed: int | None = None,
        duration: str | None = None,
        speed: float = 1.0,
        payload_addrs: Sequence[int] = (12,),
        ground_addr: int = 17,
        zmq: bool = False,
        record: bool = True,
        binary: str | None = None,
        workdir: str | os.PathLike[str] | None = None,
        args: Iterable[str] = (),
        start_timeout_s: float = 30.0,
    ) -> None:
        self.binary = binary or find_binary()
        self.scenario = scenario
        self.seed = seed
        self.duration = duration
        self.speed = speed
        self.payload_addrs = tuple(payload_addrs)
        self.ground_addr = ground_addr
        self.zmq = zmq
        self.record = record
        self.extra_args = list(args)
        self.start_timeout_s = start_timeout_s
        self._own_workdir = workdir is None
        self.workdir = (
            Path(workdir) if workdir is not None else Path(tempfile.mkdtemp(prefix="m6p-twin-"))
        )
        self.proc: subprocess.Popen[str] | None = None
        self.ground_kiss: str | None = None
        self.payload_kiss: str | None = None
        self.zmq_host: str | None = None
        self.returncode: int | None = None
        self._stderr: list[str] = []
        self._stdout = ""
        self._ready = threading.Event()
        self._icd: Icd | None = None
        self._nodes: list[CspNode] = []
        self._readers: list[threading.Thread] = []
        self._unnamed_links = 0

    # -- the process ---------------------------------------------------------------------

    @property
    def recording(self) -> Path | None:
        """The run's MCAP recording (complete after :meth:`stop`)."""
        return self.workdir / "run.mcap" if self.record else None

    def command_line(self) -> list[str]:
        argv = [self.binary, "run"]
        if self.scenario is not None:
            s = str(self.scenario)
            if "\n" in s:
                path = self.workdir / "scenario.toml"
                path.write_text(s)
                s = str(path)
            argv.append(s)
        argv += ["--realtime", "--speed", repr(float(self.speed))]
        if self.duration is None:
            argv.append("--forever")
        else:
            argv += ["--duration", str(self.duration)]
        if self.seed is not None:
            argv += ["--seed", str(self.seed)]
        if self.record:
            argv += ["--record", str(self.recording)]
        argv += ["--kiss-listen", "127.0.0.1:0", "--kiss-addr", str(self.ground_addr)]
        if self.payload_addrs:
            if self.zmq:
                # A loopback address of its own, so that twins run side by side.
                self.zmq_host = f"127.0.{random.randint(1, 254)}.{random.randint(2, 254)}"
                argv += ["--zmq-hub", self.zmq_host]
            else:
                argv += ["--kiss-listen", "127.0.0.1:0"]
            for a in self.payload_addrs:
                argv += ["--kiss-addr", str(a)]
        return argv + self.extra_args

    def start(self) -> Self:
        """Start the twin and wait until its links listen."""
        argv = self.command_line()
        self.proc = subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            errors="replace",
        )
        self._readers = [
            threading.Thread(target=self._read_stderr, daemon=True),
            threading.Thread(target=self._read_stdout, daemon=True),
        ]
        for r in self._readers:
            r.start()
        deadline = time.monotonic() + self.start_timeout_s
        while not self._ready.wait(0.05):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                why = "exited" if self.returncode is not None else "not listening in time"
                if self._unnamed_links and self.ground_kiss is None:
                    why += (
                        " (its KISS/TCP lines name no CSP addresses: an m6p-twin older than "
                        "this package? Rebuild it: cargo build --release -p m6p-twin)"
                    )
                raise TwinError(
                    f"{' '.join(argv)}: {why} (status {self.returncode}):\n" + self.output[-4000:]
                )
        return self

    def _read_stderr(self) -> None:
        assert self.proc is not None and self.proc.stderr is not None
        kiss_payloads = bool(self.payload_addrs) and not self.zmq
        for line in self.proc.stderr:
            self._stderr.append(line)
            m = _LISTENING.search(line)
            if m and not m.group(3):
                self._unnamed_links += 1
            if m and m.group(3):
                ids = [int(a) for a in m.group(3).split(",")]
                addr = f"{m.group(1)}:{m.group(2)}"
                if ids == [self.ground_addr]:
                    self.ground_kiss = addr
                elif kiss_payloads and ids == list(self.payload_addrs):
                    self.payload_kiss = addr
                if self.ground_kiss is not None and (
                    self.payload_kiss is not None or not kiss_payloads
                ):
                    self._ready.set()

    def _read_stdout(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        self._stdout = self.proc.stdout.read()

    @property
    def output(self) -> str:
        """What the twin printed: its log (stderr), then its report (stdout, after the
        run)."""
        return "".join(self._stderr) + self._stdout

    @property
    def report(self) -> str:
        """The run's report (the table and the expectations), after :meth:`stop`."""
        return self._stdout

    def stop(self, timeout_s: float = 30.0) -> int | None:
        """Stop the run as Ctrl-C does (the report and the recording are complete), close
        the nodes made by :meth:`ground` and :meth:`payload`, and return the exit status: 1
        when the run was stopped before its end (an interrupted run is no result, whatever
        held so far; the report says ``interrupted at``), else 0 when every expectation of
        the scenario held. A run with a ``duration`` ends by itself: :meth:`wait`."""
        for n in self._nodes:
            n.close()
        self._nodes.clear()
        if self.proc is None:
            return self.returncode
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.returncode = self.proc.returncode
        # The readers take the last lines, then the pipes are closed.
        for r in self._readers:
            r.join(timeout=5.0)
        for pipe in (self.proc.stdout, self.proc.stderr):
            if pipe is not None:
                pipe.close()
        return self.returncode

    def wait(self, timeout_s: float | None = None) -> int | None:
        """Wait for a run with a ``duration`` to end by itself."""
        if self.proc is not None:
            self.proc.wait(timeout_s)
        return self.stop()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def cleanup(self) -> None:
        """Remove the working directory, when this object made it."""
        if self._own_workdir:
            shutil.rmtree(self.workdir, ignore_errors=True)

    # -- nodes ---------------------------------------------------------------------------

    @property
    def icd(self) -> Icd:
        """The ICD of this twin's binary (``m6p-twin icd --json``)."""
        if self._icd is None:
            self._icd = Icd.from_twin(self.binary)
        return self._icd

    def ground(self, timeout_s: float = 5.0) -> CspNode:
        """A CSP node as the ground station (``ground_addr``) on the ground's link."""
        if self.ground_kiss is None:
            raise TwinError("the twin is not started")
        node = CspNode(KissTcp(self.ground_kiss), self.ground_addr, self.icd, timeout_s)
        self._nodes.append(node)
        return node

    def payload(self, addr: int | None = None, timeout_s: float = 5.0) -> CspNode:
        """A CSP node as payload ``addr`` (default: the first of ``payload_addrs``) on
        the payloads' link (KISS/TCP, or the ZMQ hub)."""
        a = self.payload_addrs[0] if addr is None else addr
        if a not in self.payload_addrs:
            raise TwinError(f"payload {a} is not one of this twin's {list(self.payload_addrs)}")
        link: Link
        if self.zmq:
            assert self.zmq_host is not None
            link = ZmqHub(self.zmq_host, a)
        else:
            if self.payload_kiss is None:
                raise TwinError("the twin is not started")
            link = KissTcp(self.payload_kiss)
        node = CspNode(link, a, self.icd, timeout_s)
        self._nodes.append(node)
        # Until the twin has taken the connection (and a hub the subscription), what is
        # sent to the payload has nowhere to go: a ping to the PC answered says it has.
        deadline = time.monotonic() + 10.0
        while True:
            try:
                node.ping(6, timeout_s=0.5)
                break
            except TimeoutError:
                if time.monotonic() > deadline:
                    raise TwinError(f"payload {a}: the PC does not answer its pings") from None
        return node

    # -- results -------------------------------------------------------------------------

    def downlink(self, session: int, run: int = 1) -> bytes:
        """The bytes session ``session``'s run ``run`` downlinked over the S-band (after
        :meth:`stop`; needs ``record``)."""
        if self.recording is None:
            raise TwinError("the downlinked files go beside the recording: start with record=True")
        path = self.recording.with_suffix(".downlink") / f"session-{session}-run{run}.bin"
        if not path.exists():
            raise TwinError(f"{path}: no such file (did session {session} run?)")
        return path.read_bytes()
