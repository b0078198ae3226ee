"""What ships with the package besides code: the configurations, found through
importlib.resources.

``uvd/config`` is a link to the project's ``config/`` (the one place operators and the docs
know), so setuptools ships ``config/*.toml`` and ``config/zenoh/*.json5`` inside the package
and :func:`importlib.resources.files` finds them in a checkout, an editable install and an
installed wheel alike. (Vehicles ship as ``uvd/vehicles/*.toml``, schemas as
``uvd/telemetry/schemas/*.json``, the CAN object dictionaries as ``drivers/can/*.eds``.)

A utility: imports no layer, so that sim_bridge's helpers find the embedded default too.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["CONFIG_DIR", "DEFAULT_CONFIG", "shipped_configs", "config_path"]

#: The shipped configurations (``config/*.toml`` of the checkout): package data. ``uvd/config``
#: is a link to the project's ``config/``, so setuptools ships them inside the package and
#: importlib.resources finds them in a checkout, an editable install and an installed wheel
#: alike (resolved: in a checkout, messages name ``config/…``).
CONFIG_DIR = Path(str(resources.files("uvd") / "config")).resolve()
#: The embedded default: the simulated vehicle, everything local (``config/sim.toml``).
DEFAULT_CONFIG = CONFIG_DIR / "sim.toml"


def shipped_configs() -> list[str]:
    """Names of the shipped configurations (``sim``, ``sim-bluerov2``, …)."""
    return sorted(p.stem for p in CONFIG_DIR.glob("*.toml"))


def config_path(name_or_path: str | Path) -> Path:
    """The file of ``name_or_path``: an existing file as it is; else the shipped configuration
    of that name (``sim-bluerov2`` or ``sim-bluerov2.toml``), so that an installed package
    runs ``uvd demo --config sim-bluerov2`` with no checkout; else the path itself (reading it
    then fails naming it)."""
    p = Path(name_or_path)
    if p.exists() or len(p.parts) != 1:
        return p
    shipped = CONFIG_DIR / (p.name if p.suffix == ".toml" else f"{p.name}.toml")
    return shipped if shipped.is_file() else p
