"""A payload session served from Python reaches the ground byte for byte."""

import pytest

from m6p import CspNode, Payload, Session, Twin


def test_a_session_served_from_python_is_downlinked_byte_for_byte(
    twin: Twin, ground: CspNode, payload: Payload
) -> None:
    session = Session(ground, 1)
    session.setup(duration_s="10s", max_packets=20, poll_frame_size=200, sync_message="go")
    payload.wait_polls(20)
    status = session.wait_done()
    assert status.name("last_result") == "DONE"
    assert payload.syncs == [b"go"]
    twin.stop()
    assert len(payload.sent) > 20 * 60
    assert twin.downlink(1) == bytes(payload.sent)


@pytest.mark.twin(zmq=True)
def test_the_same_session_over_the_zmq_hub(twin: Twin, ground: CspNode, payload: Payload) -> None:
    Session(ground, 1).setup(duration_s="5s", max_packets=5, poll_frame_size=64)
    payload.wait_polls(5)
    Session(ground, 1).wait_done()
    twin.stop()
    assert twin.downlink(1) == bytes(payload.sent)
