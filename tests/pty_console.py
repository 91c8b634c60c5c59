#!/usr/bin/env python3
"""Drive a program on a pseudo-terminal, as a person at a keyboard would: start
`COMMAND...` on a new pty, type each KEYS argument (Python escapes: `\\t` Tab, `\\r`
Enter, `\\x04` Ctrl-D) after the program has been quiet for a moment, and print everything
it wrote. Used by crates/twin/tests/kiss_tcp.rs for `m6p-twin gs`'s interactive console
(line editing, Tab completion, history), which only a terminal shows.

    pty_console.py 'fc tmg\\t\\r' '\\x04' -- m6p-twin gs --connect 127.0.0.1:52001
"""
import os
import pty
import select
import signal
import sys
import time


def read_until_quiet(fd, quiet_s=0.6, limit_s=10.0):
    out = b""
    end = time.monotonic() + limit_s
    last = time.monotonic()
    while time.monotonic() < end and time.monotonic() - last < quiet_s:
        r, _, _ = select.select([fd], [], [], 0.05)
        if r:
            try:
                chunk = os.read(fd, 4096)
            except OSError:
                break
            if not chunk:
                break
            out += chunk
            last = time.monotonic()
    return out


def main():
    if "--" not in sys.argv:
        sys.exit("usage: pty_console.py KEYS... -- COMMAND [ARGS...]")
    i = sys.argv.index("--")
    keys = [k.encode().decode("unicode_escape").encode("latin-1") for k in sys.argv[1:i]]
    command = sys.argv[i + 1:]
    pid, fd = pty.fork()
    if pid == 0:
        os.execvp(command[0], command)
    out = read_until_quiet(fd, quiet_s=1.0)
    for k in keys:
        os.write(fd, k)
        out += read_until_quiet(fd)
    # Whatever the program still writes until it exits and its side of the pty closes.
    out += read_until_quiet(fd, quiet_s=30.0, limit_s=30.0)
    done, status = os.waitpid(pid, os.WNOHANG)
    if done == 0:  # still running after 30 s: it did not leave
        os.kill(pid, signal.SIGKILL)
        _, status = os.waitpid(pid, 0)
    sys.stdout.write(out.decode(errors="replace"))
    sys.exit(os.waitstatus_to_exitcode(status))


if __name__ == "__main__":
    main()
