"""Against a real twin: every telemetry command answered and decoded, and the package's
ICD is the twin's."""

import time

import pytest

from m6p import CspNode, Icd, IcdError, Twin

TELEMETRY = [
    ("FC.TMGEN", None),
    ("FC.TMATP", None),
    ("FC.TMACD", None),
    ("FC.TMSENS", None),
    ("FC.TMRAWSENS", None),
    ("FC.TMALL", None),
    ("EPS.TMEPS", None),
    ("ECU.TMECU", None),
    ("COMM.TMCOMM", 1),
    ("COMM.TMCOMM", 2),
    ("PC.TMPC", None),
]


def test_the_packages_icd_is_the_twins(twin: Twin) -> None:
    assert twin.icd.doc == Icd.load().doc


def test_every_telemetry_command_is_answered_and_decoded(ground: CspNode) -> None:
    for name, to in TELEMETRY:
        r = ground.command(name, to=to)
        assert r.ok, name
        assert len(r.data) == r.command.reply.max_bytes, name
        assert r.leaves(), name
    assert ground.command("COMM.TMCOMM", to=2).name("role") == "secondary"
    eps = ground.command("EPS.TMEPS")
    assert eps["panel_count"] == 6 and eps.value("panel_count", int) == 6
    assert len(eps.array("panels_w", float)) == 8


def test_a_mode_change_is_seen_in_tmgen(ground: CspNode) -> None:
    assert ground.command("FC.TMGEN").name("current_mode") == "detumble"
    assert ground.command("FC.ATCMDSET", mode="idle").ok
    # The mode changes at the control law's next step (10 Hz).
    for _ in range(20):
        if ground.command("FC.TMGEN").name("current_mode") == "idle":
            break
        time.sleep(0.1)
    assert ground.command("FC.TMGEN").name("current_mode") == "idle"
    with pytest.raises(IcdError, match="mode"):
        ground.command("FC.ATCMDSET", mode="upside down")


def test_stopping_gives_the_report_and_a_complete_recording(twin: Twin, ground: CspNode) -> None:
    assert ground.ping(3) < 2.0
    twin.stop()
    assert "link listen 127.0.0.1" in twin.report
    recording = twin.recording
    assert recording is not None and recording.stat().st_size > 1000
    assert recording.read_bytes()[-8:] == b"\x89MCAP0\r\n"
