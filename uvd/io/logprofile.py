"""Log profiles: which topic / message / field of another system's recording is which signal,
in which unit and frame, and which time stamp to trust (TOML, validated like the configuration).

A profile names up to five signals:

=====================  ========================================  ===============================
signal                 meaning                                   units
=====================  ========================================  ===============================
``angular_rate``       body angular rate [p, q, r]               ``rad/s``, ``deg/s``
``attitude``           roll, pitch, yaw (ZYX Euler)              ``rad``, ``deg``
``depth``              depth, or pressure turned into depth      ``m``, ``Pa``, ``hPa``, ``mbar``
``linear_velocity``    body [u, v, w] (``frame`` body) or world  ``m/s``, ``mm/s``
                       [N, E, D] (``frame`` world, rotated into
                       the body with the attitude)
``thrusters``          per-thruster commands                     ``pwm_us``, ``normalised``
=====================  ========================================  ===============================

Each signal: ``topic``; either ``field`` (an attribute path, e.g. ``data`` or ``angular_velocity``)
plus ``index`` (the elements of an array field) or ``fields`` (one attribute per component,
e.g. ``["rollspeed", "pitchspeed", "yawspeed"]``); ``unit``; ``frame`` — ``frd`` (x forward,
y starboard, z down: ours, ArduPilot's body frame) or ``flu`` (ROS REP 103 body frame) for
body signals, ``ned`` (ours, ArduPilot's) or ``enu`` (ROS) for world ones; ``scale`` and
``offset`` (after the unit) for pressure (``reference_pa``, ``density_kg_m3``, ``gravity_m_s2``);
``match`` — only messages whose fields have these values (``{I = 1}``: one sensor instance of
several on the same message type).

Top level: ``name``, ``description``, ``format`` (a :mod:`uvd.io.logs` name), ``time``
(``"receive"`` — the recorder's stamp — or ``"field:<name>"`` with ``time_unit``), ``rate_hz``
(the one clock everything is put on), ``resample`` (``"hold"`` — zero-order hold of the last
sample — or ``"interpolate"``), ``max_gap_s`` (a signal without a sample for longer than this
cuts the run: nothing is invented across a gap), ``span`` (``"all"`` or ``"thrusters"``: only
the interval between the first and last thruster command), ``vehicle`` (default vehicle).

Built-in profiles are package data (``uvd/logprofiles/*.toml``); any other file is given by path.
Errors are :class:`~uvd.errors.ConfigError` naming the file and key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from uvd.errors import ConfigError
from uvd.io.toml import TomlFileError, other_kind, read_toml

SIGNALS = ("angular_rate", "attitude", "depth", "linear_velocity", "thrusters")
UNITS = {"angular_rate": ("rad/s", "deg/s"), "attitude": ("rad", "deg"),
         "depth": ("m", "Pa", "hPa", "mbar"), "linear_velocity": ("m/s", "mm/s", "cm/s"),
         "thrusters": ("pwm_us", "normalised")}
FRAMES = {"angular_rate": ("frd", "flu"), "attitude": ("ned", "enu"), "depth": ("down", "up"),
          "linear_velocity": ("frd", "flu", "ned", "enu"), "thrusters": ("vehicle",)}
_SIGNAL_KEYS = {"topic", "field", "index", "fields", "unit", "frame", "scale", "offset",
                "reference_pa", "density_kg_m3", "gravity_m_s2", "match"}
_TOP_KEYS = {"name", "description", "format", "time", "time_unit", "rate_hz", "resample",
             "max_gap_s", "span", "vehicle", "signals"}
_REQUIRED = ("angular_rate", "attitude", "thrusters")


@dataclass(frozen=True)
class SignalSpec:
    """Where one signal is in the log and what it means."""

    name: str
    topic: str
    field: str | None
    index: tuple[int, ...] | None
    fields: tuple[str, ...] | None
    unit: str
    frame: str
    scale: float = 1.0
    offset: float = 0.0
    reference_pa: float = 0.0
    density_kg_m3: float = 1000.0
    gravity_m_s2: float = 9.81
    match: tuple = ()

    @property
    def width(self) -> int:
        if self.fields is not None:
            return len(self.fields)
        return len(self.index) if self.index is not None else 1


@dataclass(frozen=True)
class LogProfile:
    """A validated log profile (see the module docstring)."""

    name: str
    description: str
    format: str | None
    time: str
    time_unit: str
    rate_hz: float
    resample: str
    max_gap_s: float
    span: str
    vehicle: str | None
    signals: dict
    source: str = ""

    def topics(self) -> frozenset[str]:
        return frozenset(s.topic for s in self.signals.values())


def _builtin_root():
    return resources.files("uvd") / "logprofiles"


def builtin_profiles() -> list[str]:
    """Names of the built-in profiles (``uvd/logprofiles/*.toml``)."""
    return sorted(p.name[:-5] for p in _builtin_root().iterdir() if p.name.endswith(".toml"))


def _match(m, where: str) -> tuple:
    if not isinstance(m, dict) or not all(isinstance(v, (int, float, str, bool))
                                          for v in m.values()):
        raise ConfigError(f"{where}: match must be a table of field = value (e.g. {{I = 1}})")
    return tuple(sorted(m.items()))


def _number(t: dict, key: str, default: float, where: str) -> float:
    """``t[key]`` (or ``default``) as a finite float; else a ConfigError naming the key."""
    x = t.get(key, default)
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        raise ConfigError(f"{where}: {key} must be a finite number, got {x!r}")
    return float(x)


def _positive(t: dict, key: str, default: float, where: str, *, most: float = math.inf
              ) -> float:
    """:func:`_number`, and > 0 (and ≤ ``most``); else a ConfigError naming the key."""
    x = _number(t, key, default, where)
    if not 0.0 < x <= most:
        bound = "> 0" if most == math.inf else f"in (0, {most:g}]"
        raise ConfigError(f"{where}: {key} must be {bound}, got {x!r}")
    return x


def _text(t: dict, key: str, default: str, where: str) -> str:
    """``t[key]`` (or ``default``), which must be a string; else a ConfigError naming it."""
    x = t.get(key, default)
    if not isinstance(x, str):
        raise ConfigError(f"{where}: {key} must be a string, got {x!r}")
    return x


def _signal(name: str, t: dict, where: str) -> SignalSpec:
    if not isinstance(t, dict):
        raise ConfigError(f"{where}: must be a table")
    bad = set(t) - _SIGNAL_KEYS
    if bad:
        raise ConfigError(f"{where}: unknown key(s) {sorted(bad)}")
    for k in ("topic", "unit", "frame"):
        if k not in t:
            raise ConfigError(f"{where}: missing key {k!r}")
    if ("field" in t) == ("fields" in t):
        raise ConfigError(f"{where}: give either 'field' (with 'index' for an array) or "
                          "'fields' (one per component)")
    for k in ("topic", "field", "unit", "frame"):
        if k in t and not isinstance(t[k], str):
            raise ConfigError(f"{where}: {k} must be a string, got {t[k]!r}")
    if "fields" in t and not (isinstance(t["fields"], list) and t["fields"]
                              and all(isinstance(x, str) for x in t["fields"])):
        raise ConfigError(f"{where}: fields must be a list of field names, got "
                          f"{t['fields']!r}")
    if t["unit"] not in UNITS[name]:
        raise ConfigError(f"{where}: unit {t['unit']!r} is not one of {UNITS[name]}")
    if t["frame"] not in FRAMES[name]:
        raise ConfigError(f"{where}: frame {t['frame']!r} is not one of {FRAMES[name]}")
    fields = tuple(t["fields"]) if "fields" in t else None
    index = None
    if "index" in t:
        if not (isinstance(t["index"], list) and all(
                isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in t["index"])):
            raise ConfigError(f"{where}: index must be a list of integers >= 0")
        index = tuple(t["index"])
    spec = SignalSpec(name=name, topic=t["topic"], field=t.get("field"), index=index,
                      fields=fields, unit=t["unit"], frame=t["frame"],
                      scale=_number(t, "scale", 1.0, where),
                      offset=_number(t, "offset", 0.0, where),
                      reference_pa=_number(t, "reference_pa", 0.0, where),
                      density_kg_m3=_positive(t, "density_kg_m3", 1000.0, where),
                      gravity_m_s2=_positive(t, "gravity_m_s2", 9.81, where),
                      match=_match(t.get("match", {}), where))
    want = {"angular_rate": 3, "attitude": 3, "depth": 1, "linear_velocity": 3}.get(name)
    if want is not None and spec.width != want:
        raise ConfigError(f"{where}: {name} needs {want} component(s), the profile gives "
                          f"{spec.width}")
    return spec


def profile_from_mapping(doc: dict, *, where: str) -> LogProfile:
    """Validate a parsed profile; errors name ``where`` and the key."""
    bad = set(doc) - _TOP_KEYS
    kind = other_kind(doc, "profile")
    if kind:
        raise ConfigError(f"{where}: this is {kind}, not a log profile")
    if bad:
        raise ConfigError(f"{where}: unknown key(s) {sorted(bad)}")
    sig = doc.get("signals")
    if sig is None:
        raise ConfigError(f"{where}: missing [signals]")
    if not isinstance(sig, dict):
        raise ConfigError(f"{where}: [signals] must be a table, got {type(sig).__name__} "
                          f"{sig!r:.80}")
    bad = set(sig) - set(SIGNALS)
    if bad:
        raise ConfigError(f"{where}: [signals]: unknown signal(s) {sorted(bad)}; known "
                          f"{list(SIGNALS)}")
    missing = [s for s in _REQUIRED if s not in sig]
    if missing:
        raise ConfigError(f"{where}: [signals]: identification needs {missing}")
    signals = {k: _signal(k, v, f"{where}: [signals.{k}]") for k, v in sig.items()}
    time = _text(doc, "time", "receive", where)
    if time != "receive" and not time.startswith("field:"):
        raise ConfigError(f"{where}: time must be 'receive' or 'field:<name>', got {time!r}")
    time_unit = _text(doc, "time_unit", "s", where)
    if time_unit not in ("s", "ms", "us", "ns"):
        raise ConfigError(f"{where}: time_unit must be s, ms, us or ns, got {time_unit!r}")
    resample = _text(doc, "resample", "hold", where)
    if resample not in ("hold", "interpolate"):
        raise ConfigError(f"{where}: resample must be 'hold' or 'interpolate', got "
                          f"{resample!r}")
    span = _text(doc, "span", "all", where)
    if span not in ("all", "thrusters"):
        raise ConfigError(f"{where}: span must be 'all' or 'thrusters', got {span!r}")
    rate = _positive(doc, "rate_hz", 50.0, where, most=10000.0)
    gap = _positive(doc, "max_gap_s", 0.5, where)
    fmt = doc.get("format")
    if fmt is not None:
        from uvd.io.logs import FORMATS
        if not isinstance(fmt, str) or fmt not in FORMATS:
            raise ConfigError(f"{where}: format {fmt!r} is not one of {sorted(FORMATS)}")
    vehicle = doc.get("vehicle")
    if vehicle is not None and not isinstance(vehicle, str):
        raise ConfigError(f"{where}: vehicle must be a vehicle's name or file, got {vehicle!r}")
    return LogProfile(name=_text(doc, "name", "", where),
                      description=_text(doc, "description", "", where),
                      format=fmt, time=time, time_unit=time_unit, rate_hz=rate,
                      resample=resample, max_gap_s=gap, span=span, vehicle=vehicle,
                      signals=signals, source=where)


def load_profile(name_or_path: str | Path) -> LogProfile:
    """A built-in profile by name or a profile TOML by path, validated."""
    p = Path(name_or_path)
    if p.suffix == ".toml" and p.is_file():
        f, where = p, str(p)
    else:
        f = _builtin_root() / f"{name_or_path}.toml"
        if not f.is_file():
            raise ConfigError(f"unknown log profile {str(name_or_path)!r}: not a file, and not "
                              f"one of the built-in profiles {builtin_profiles()}")
        where = f"log profile {name_or_path}"
    try:
        doc = read_toml(f, "the log profile")
    except TomlFileError as exc:
        raise ConfigError(f"{where}: {exc.reason}") from exc
    prof = profile_from_mapping(doc, where=where)
    if not prof.name:
        prof = LogProfile(**{**prof.__dict__, "name": p.stem})
    return prof
