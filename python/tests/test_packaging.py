"""The package as a payload team meets it outside this repository: ``pytest --m6p-twin
PATH`` in either form leaves pytest's rootdir and configuration file where they were, and
building the package writes nothing into its source tree."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import m6p

# A project of a payload team's: its configuration names its test directory, and its test
# says where pytest put the rootdir and which configuration file it read.
PROJECT_CONFIG = '[tool.pytest.ini_options]\ntestpaths = ["checks"]\n'
PROJECT_TEST = """\
from pathlib import Path


def test_where(pytestconfig):
    project = Path(__file__).resolve().parent.parent
    assert pytestconfig.rootpath.resolve() == project
    assert pytestconfig.inipath is not None
    assert pytestconfig.inipath.resolve() == project / "pyproject.toml"
    assert pytestconfig.getoption("--m6p-twin") == "../bin/m6p-twin"
"""


def _env() -> dict[str, str]:
    """This environment, with this test's own ``m6p`` first on the path."""
    env = dict(os.environ)
    env.pop("PYTEST_ADDOPTS", None)
    here = str(Path(m6p.__file__).resolve().parent.parent)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (here, env.get("PYTHONPATH")) if p)
    return env


@pytest.mark.parametrize(
    "args",
    [
        ["--m6p-twin", "../bin/m6p-twin"],
        ["--m6p-twin=../bin/m6p-twin"],
        ["--m6p-twin", "../bin/m6p-twin", "checks"],
        ["checks/test_where.py", "--m6p-twin", "../bin/m6p-twin"],
    ],
    ids=["space", "equals", "space-then-path", "path-then-space"],
)
def test_the_binary_option_leaves_the_rootdir_and_configuration_alone(
    tmp_path: Path, args: list[str]
) -> None:
    # The binary in a folder of its own beside the project (it is never run here).
    (tmp_path / "bin").mkdir()
    (tmp_path / "bin" / "m6p-twin").touch()
    project = tmp_path / "project"
    (project / "checks").mkdir(parents=True)
    (project / "pyproject.toml").write_text(PROJECT_CONFIG)
    (project / "checks" / "test_where.py").write_text(PROJECT_TEST)
    # `-p m6p.pytest_plugin` loads the plugin where the package is not installed; where it
    # is, its entry point names the same module, loaded once, at the same point (after
    # pytest has found the rootdir).
    pytest_args = ["-p", "m6p.pytest_plugin", "-p", "no:cacheprovider", "-W", "error", *args]
    run = subprocess.run(
        [sys.executable, "-m", "pytest", *pytest_args],
        check=False,
        cwd=project,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    out = run.stdout + run.stderr
    assert run.returncode == 0, out
    assert f"rootdir: {project}" in out, out
    assert "configfile: pyproject.toml" in out, out
    assert "1 passed" in out, out


def _files(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


def test_building_the_package_writes_nothing_into_its_source(tmp_path: Path) -> None:
    # The package's source beside these tests (python/), as pip would be given it.
    source = Path(__file__).resolve().parent.parent
    copy = tmp_path / "python"
    copy.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(source / name, copy / name)
    shutil.copytree(
        source / "src",
        copy / "src",
        ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"),
    )
    before = _files(copy)
    wheels = tmp_path / "wheels"
    build = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--quiet",
            "--no-deps",
            "-w",
            str(wheels),
            str(copy),
        ],
        check=False,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert build.returncode == 0, build.stdout + build.stderr
    assert _files(copy) == before, sorted(_files(copy) - before)
    # The wheel holds the package's data and its pytest plugin.
    [wheel] = wheels.glob("m6p-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        assert {"m6p/icd.json", "m6p/py.typed", "m6p/pytest_plugin.py"} <= names, names
        [entry_points] = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
        assert "m6p.pytest_plugin" in z.read(entry_points).decode()
