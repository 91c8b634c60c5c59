"""pytest fixtures for testing against the twin (registered when the package is
installed; otherwise add ``pytest_plugins = ["m6p.pytest_plugin"]`` to a conftest.py):

- ``twin``: a :class:`m6p.twin.Twin` on the embedded default scenario, started for the
  test and stopped after it. Choose another with ``@pytest.mark.twin(scenario=...,
  seed=..., zmq=True, ...)`` (any :class:`~m6p.twin.Twin` argument) or by overriding
  the ``twin_options`` fixture.
- ``ground``: a :class:`m6p.node.CspNode` as ground station 17 of that twin.
- ``payload``: a :class:`m6p.session.Payload` serving payload 12's polling sessions with
  :func:`m6p.session.counter_frames` (``payload.source = ...`` to change the data).

Options: ``--m6p-twin PATH`` or ``--m6p-twin=PATH`` (the binary; default
:func:`m6p.twin.find_binary`) and ``--m6p-keep`` (keep each twin's working directory:
recording, downlink, log).

pytest finds its rootdir and configuration file before it loads installed plugins, from
the paths on the command line: in the space form it takes ``PATH`` for a test path then
(the binary's folder would become the rootdir, and the project's own ``pytest.ini`` or
``pyproject.toml`` go unread). The plugin finds them again as pytest would have without
``PATH``, before the first conftest is read (:func:`pytest_load_initial_conftests`).
"""

from __future__ import annotations

import inspect
from collections.abc import Iterator
from typing import Any, cast

import pytest

from .node import CspNode
from .session import Payload
from .twin import Twin, TwinOptions


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("m6p", "M6P twin")
    group.addoption(
        "--m6p-twin",
        default=None,
        metavar="PATH",
        help="the m6p-twin binary to run (--m6p-twin PATH or --m6p-twin=PATH)",
    )
    group.addoption(
        "--m6p-keep",
        action="store_true",
        help="keep each twin's working directory (recording, downlinked files)",
    )


@pytest.hookimpl(tryfirst=True)
def pytest_load_initial_conftests(early_config: pytest.Config, args: list[str]) -> None:
    """After ``--m6p-twin PATH`` (the space form), find the rootdir and the configuration
    file as pytest would have without ``PATH``, which it took for a test path."""
    if "--m6p-twin" in args:
        _find_root_again(early_config)


def _find_root_again(config: pytest.Config) -> None:
    """Find ``config``'s rootdir and configuration file again from the test paths it knows
    now (pytest's own ``determine_setup``, whose arguments differ between versions), and
    the conftest boundary that came from them, unless given."""
    from _pytest.config import findpaths

    ns = config.known_args_namespace
    known: dict[str, Any] = {
        "inifile": ns.inifilename,
        "args": list(ns.file_or_dir),
        "rootdir_cmd_arg": ns.rootdir or None,
        "invocation_dir": config.invocation_params.dir,
        "override_ini": getattr(ns, "override_ini", None),
        "config": config,
    }
    wanted = inspect.signature(findpaths.determine_setup).parameters
    found = findpaths.determine_setup(**{k: v for k, v in known.items() if k in wanted})
    rootpath, inipath, inicfg = found[0], found[1], found[2]
    if (rootpath, inipath) == (config.rootpath, config.inipath):
        return
    derived_cut = str(config.inipath.parent if config.inipath else config.rootpath)
    config._rootpath = rootpath
    config._inipath = inipath
    config._inicfg = inicfg
    config._inicache.clear()
    config._parser.extra_info["rootdir"] = str(rootpath)
    config._parser.extra_info["inifile"] = str(inipath)
    if ns.confcutdir is None or ns.confcutdir == derived_cut:
        ns.confcutdir = str(inipath.parent if inipath else rootpath)


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
