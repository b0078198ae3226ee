"""uvd outside this checkout: a wheel built from the repository, installed with its dependencies
(the tested versions of constraints.txt) into a new virtual environment in an empty directory,
finds its embedded default and every shipped configuration, vehicle and object dictionary
through importlib.resources, and ``uvd check-config`` accepts every shipped configuration."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: what is not the package's source (a built tree would otherwise carry the test venv along)
_NOT_SOURCE = shutil.ignore_patterns(".venv", ".git", "build", "dist", "*.egg-info",
                                     "__pycache__", ".pytest_cache", ".hypothesis",
                                     ".ruff_cache", "tests", "docs", "out")


def _run(argv, cwd, timeout=300) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    r = subprocess.run([str(a) for a in argv], cwd=cwd, capture_output=True, text=True,
                       timeout=timeout, env=env)
    assert r.returncode == 0, f"{argv}: rc {r.returncode}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r


def test_constraints_pin_every_dependency_and_not_uvd():
    """constraints.txt pins (==) every requirement of pyproject.toml, dev extras included."""
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, _, version = line.partition("==")
            assert version, f"constraints.txt: {line!r} is not pinned with =="
            pins[name.lower().replace("_", "-")] = version
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    wanted = project["dependencies"] + project["optional-dependencies"]["dev"]
    names = {req.split(">")[0].split("=")[0].split("<")[0].split("[")[0].strip().lower()
             .replace("_", "-") for req in wanted}
    assert "uvd" not in pins
    assert not names - set(pins), f"not pinned in constraints.txt: {sorted(names - set(pins))}"


@pytest.mark.slow
@pytest.mark.timeout(900)  # a wheel build and an install of ~60 wheels: ~1 min quiet, minutes
def test_the_wheel_runs_outside_the_checkout(tmp_path):  # on a loaded machine
    src, wheels, venv, empty = (tmp_path / n for n in ("src", "wheels", "venv", "empty"))
    empty.mkdir()
    # the tracked source only (the config/ link resolved by the build, as in a fresh clone)
    shutil.copytree(ROOT, src, symlinks=True, ignore=_NOT_SOURCE)
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", wheels, src], empty)
    (wheel,) = wheels.glob("uvd-*.whl")
    _run([sys.executable, "-m", "venv", venv], empty)
    py = venv / "bin" / "python"
    _run([py, "-m", "pip", "install", "--quiet", "--no-compile", "-c", ROOT / "constraints.txt",
          wheel], empty, timeout=600)
    # every file the daemon needs at run time, from the installed package
    shipped = sorted(p.stem for p in (ROOT / "config").glob("*.toml"))
    probe = ("from uvd.runtime.config import DEFAULT_CONFIG, CONFIG_DIR, shipped_configs\n"
             "from drivers.can.config import DEFAULT_AMPLIFIER_EDS, DEFAULT_PRESSURE_EDS\n"
             "from uvd.io.vehicle import builtin_vehicles\n"
             "for p in (DEFAULT_CONFIG, DEFAULT_AMPLIFIER_EDS, DEFAULT_PRESSURE_EDS):\n"
             "    assert p.is_file(), p\n"
             "print(CONFIG_DIR)\nprint(','.join(shipped_configs()))\n"
             "print(','.join(builtin_vehicles()))\n")
    out = _run([py, "-c", probe], empty).stdout.splitlines()
    config_dir = Path(out[0])
    assert venv in config_dir.parents and ROOT not in config_dir.parents
    assert out[1].split(",") == shipped
    assert out[2].split(",") == sorted(p.stem for p in (ROOT / "uvd" / "vehicles").glob("*.toml"))
    assert sorted(p.name for p in (config_dir / "zenoh").iterdir()) == \
        sorted(p.name for p in (ROOT / "config" / "zenoh").iterdir())
    assert not (config_dir / "uvd.service").exists()  # a deployment file, not package data
    r = _run([venv / "bin" / "uvd", "check-config", "--shipped"], empty)
    assert [ln.split(":")[0] for ln in r.stdout.splitlines() if ": OK" in ln] == shipped
