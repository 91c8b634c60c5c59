"""pytest fixtures for testing against the twin (registered when the package is
installed; otherwise add ``pytest_plugins = ["m6p.pytest_plugin"]`` to a conftest.py):

- ``twin``: a :class:`m6p.twin.Twin` on the embedded default scenario, started for the
  test and stopped after it. Choose another with ``@pytest.mark.twin(scenario=...,
  seed=..., zmq=True, ...)`` (any :class:`~m6p.twin.Twin` argument) or by overriding
  the ``twin_options`` fixture.
- ``ground``: a :class:`m6p.node.CspNode` as ground station 17 of that twin.
- ``payload``: a :class:`m6p.session.Payload` serving payload 12's polling sessions with
  :func:`m6p.session.counter_frames` (``payload.source = ...`` to change the data).

Options: ``--m6p-twin PATH`` (the binary; default :func:`m6p.twin.find_binary`) and
``--m6p-keep`` (keep each twin's working directory: recording, downlink, log).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import cast

import pytest

from .node import CspNode
from .session import Payload
from .twin import Twin, TwinOptions


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("m6p", "M6P twin")
    group.addoption("--m6p-twin", default=None, help="the m6p-twin binary to run")
    group.addoption(
        "--m6p-keep",
        action="store_true",
        help="keep each twin's working directory (recording, downlinked files)",
    )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "twin(**options): options for the `twin` fixture (m6p.twin.Twin's arguments)"
    )


@pytest.fixture
def twin_options(request: pytest.FixtureRequest) -> TwinOptions:
    """The `twin` fixture's :class:`~m6p.twin.Twin` arguments (from the ``twin``
    marker)."""
    marker = request.node.get_closest_marker("twin")
    if marker is None:
        return {}
    unknown = sorted(set(marker.kwargs) - TwinOptions.__optional_keys__)
    if unknown:
        raise pytest.UsageError(
            f"@pytest.mark.twin: {', '.join(unknown)}: not an argument of m6p.Twin"
        )
    # The names are Twin's; their values Twin takes or refuses when it starts.
    return cast(TwinOptions, dict(marker.kwargs))


@pytest.fixture
def twin(request: pytest.FixtureRequest, twin_options: TwinOptions) -> Iterator[Twin]:
    opts = twin_options.copy()
    binary = request.config.getoption("--m6p-twin")
    if binary and "binary" not in opts:
        opts["binary"] = binary
    t = Twin(**opts)
    keep = request.config.getoption("--m6p-keep")
    try:
        t.start()
        yield t
    finally:
        t.stop()
        if keep:
            print(f"\nm6p: the twin's files are in {t.workdir}")
        else:
            t.cleanup()


@pytest.fixture
def ground(twin: Twin) -> CspNode:
    return twin.ground()


@pytest.fixture
def payload(twin: Twin) -> Payload:
    return Payload(twin.payload())
