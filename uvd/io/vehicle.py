"""Vehicle files: the UV parameters of (2.44) plus the thrusters, as TOML.

Built-in vehicles are package data under ``uvd/vehicles/`` (``jhu-rov``, ``jhu-rov-coupled``);
any other TOML file of the same form can be given by path. :func:`load_vehicle` validates
everything it reads and names the file and the key in each error.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from uvd.errors import ConfigError, ParameterError
from uvd.io.params import params_from_mapping
from uvd.io.toml import other_kind, read_toml, refused_name
from uvd.model.thrusters import ThrustCurve, ThrusterSpec
from uvd.model.vehicle import Vehicle

_THRUSTER_KEYS = {"name", "position_m", "direction", "k_thrust", "max_thrust_n",
                  "time_constant_s", "stiction_n", "curve"}
_TOP_KEYS = {"name", "description", "parameters", "thruster_defaults", "thrusters",
             "thrust_curves"}
_CURVE_KEYS = {"name", "unit", "neutral", "dead_band", "command", "thrust_n", "source",
               "supply_voltage_v"}


def _builtin_root():
    return resources.files("uvd") / "vehicles"


def builtin_vehicles() -> list[str]:
    """Names of the built-in vehicles (the files under ``uvd/vehicles/``)."""
    return sorted(p.name[:-5] for p in _builtin_root().iterdir() if p.name.endswith(".toml"))


def vehicle_path(name_or_path: str | Path) -> Path:
    """The file of a built-in vehicle name, or ``name_or_path`` itself if it is a TOML file."""
    p = Path(name_or_path)
    if why := refused_name(p):
        raise ConfigError(f"vehicle file {str(p)!r:.80}: {why}")
    if p.suffix == ".toml" and p.exists():
        return p
    if str(name_or_path) in builtin_vehicles():  # a name, never a path into the package
        return Path(str(_builtin_root() / f"{name_or_path}.toml"))
    raise ConfigError(f"unknown vehicle {str(name_or_path)!r}: not a file, and not one of the "
                      f"built-in vehicles {builtin_vehicles()}")


def builtin_curves() -> list[str]:
    """Names of the built-in thrust curves (``uvd/vehicles/curves/*.toml``)."""
    return sorted(p.name[:-5] for p in (_builtin_root() / "curves").iterdir()
                  if p.name.endswith(".toml"))


def _curve_from_table(table: dict, where: str) -> ThrustCurve:
    bad = set(table) - _CURVE_KEYS
    if bad:
        raise ConfigError(f"{where}: unknown key(s) {sorted(bad)}")
    missing = {"command", "thrust_n"} - set(table)
    if missing:
        raise ConfigError(f"{where}: missing key(s) {sorted(missing)}")
    try:
        return ThrustCurve(command=tuple(table["command"]), thrust_n=tuple(table["thrust_n"]),
                           neutral=float(table.get("neutral", 0.0)),
                           dead_band=float(table.get("dead_band", 0.0)),
                           unit=table.get("unit", "normalised"),
                           source=str(table.get("source", "")))
    except (TypeError, ValueError, ParameterError) as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def load_curve(name: str) -> ThrustCurve:
    """A built-in thrust curve by name (e.g. ``t200``, Blue Robotics' T200)."""
    if name not in builtin_curves():  # a name, never a path (too long, or into another folder)
        raise ConfigError(f"unknown thrust curve {name!r}: not one of the built-in curves "
                          f"{builtin_curves()} nor a [thrust_curves.{name}] table of the vehicle")
    f = _builtin_root() / "curves" / f"{name}.toml"
    return _curve_from_table(read_toml(f), f"thrust curve {f}")


def _table(value, where: str) -> dict:
    """``value`` if it is a table; else a ConfigError saying what it is instead."""
    if not isinstance(value, dict):
        raise ConfigError(f"{where} must be a table, got {type(value).__name__} {value!r:.80}")
    return value


def load_vehicle(name_or_path: str | Path) -> Vehicle:
    """Load a built-in vehicle by name or a vehicle TOML file by path; validates it."""
    path = vehicle_path(name_or_path)
    doc = read_toml(path, "the vehicle")
    unknown = set(doc) - _TOP_KEYS
    if unknown:
        kind = other_kind(doc, "vehicle")
        raise ConfigError(f"{path}: " + (f"this is {kind}, not a vehicle file" if kind
                                         else f"unknown key(s) {sorted(unknown)}"))
    if "parameters" not in doc:
        raise ConfigError(f"{path}: missing [parameters]")
    params = params_from_mapping(doc["parameters"], where=f"{path}: [parameters]")
    try:
        params.validate(where=f"{path}: [parameters]")
    except ParameterError as exc:
        raise ConfigError(str(exc)) from exc
    defaults = dict(_table(doc.get("thruster_defaults", {}), f"{path}: [thruster_defaults]"))
    bad = set(defaults) - _THRUSTER_KEYS
    if bad:
        raise ConfigError(f"{path}: [thruster_defaults]: unknown key(s) {sorted(bad)}")
    curves = {name: _curve_from_table(_table(tbl, f"{path}: [thrust_curves.{name}]"),
                                      f"{path}: [thrust_curves.{name}]")
              for name, tbl in _table(doc.get("thrust_curves", {}),
                                      f"{path}: [thrust_curves]").items()}
    thrusters = doc.get("thrusters", [])
    if not isinstance(thrusters, list):
        raise ConfigError(f"{path}: thrusters must be an array of tables ([[thrusters]]), got "
                          f"{type(thrusters).__name__} {thrusters!r:.80}")
    specs = []
    for i, t in enumerate(thrusters):
        bad = set(_table(t, f"{path}: thrusters[{i}]")) - _THRUSTER_KEYS
        if bad:
            raise ConfigError(f"{path}: thrusters[{i}]: unknown key(s) {sorted(bad)}")
        kw = {**defaults, **t}
        if "curve" in kw:
            cname = kw["curve"]
            if not isinstance(cname, str):
                raise ConfigError(f"{path}: thrusters[{i}]: curve must be the name of a thrust "
                                  f"curve, got {cname!r}")
            try:
                kw["curve"] = curves[cname] if cname in curves else load_curve(cname)
            except ConfigError as exc:
                raise ConfigError(f"{path}: thrusters[{i}]: {exc}") from exc
        try:
            specs.append(ThrusterSpec(**kw))
        except (TypeError, ParameterError) as exc:
            raise ConfigError(f"{path}: thrusters[{i}]: {exc}") from exc
    if len(specs) < 6:
        raise ConfigError(
            f"{path}: a fully actuated vehicle needs >= 6 thrusters, got {len(specs)}")
    for key in ("name", "description"):
        if not isinstance(doc.get(key, ""), str):
            raise ConfigError(f"{path}: {key} must be a string, got {doc[key]!r}")
    v = Vehicle(name=doc.get("name", path.stem), description=doc.get("description", ""),
                params=params, thrusters=tuple(specs))
    rank = np.linalg.matrix_rank(v.B)
    if rank < 6:
        raise ConfigError(f"{path}: thruster matrix has rank {rank} < 6 (not fully actuated)")
    return v
