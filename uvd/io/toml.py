"""TOML files in and out. :func:`read_toml` is how every TOML file a user hands uvd is read
(configuration, vehicle, parameters, log profile, campaign, the MAVLink parameters kept for a
restart): whatever is wrong with the file comes back as one :class:`TomlFileError` saying
what. :func:`dump_toml` writes the TOML text of a configuration-like table, what the tools
write for a daemon to read (``sim-bridge``'s run configuration, the realtime replay's
configuration of the daemon under test); ``tomllib`` reads TOML but does not write it."""

from __future__ import annotations

import errno
import json
import math
import os
import tomllib
from pathlib import Path
from typing import Any

from uvd.errors import ConfigError

__all__ = ["TomlFileError", "dump_toml", "other_kind", "read_toml", "refused_name"]

#: lookup errors that only mean "not there" (those pathlib's ``exists`` answers False to)
_ABSENT = frozenset({errno.ENOENT, errno.ENOTDIR, errno.EBADF, errno.ELOOP})


class TomlFileError(ConfigError):
    """A TOML file that cannot be read: ``reason`` says why without the path (each reader
    puts the path, or the key that named the file, in front in its own words); the message
    is ``PATH: reason``."""

    def __init__(self, path: Path, reason: str):
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = path, reason


def read_toml(path: str | Path, what: str = "") -> dict[str, Any]:
    """The tables of the TOML file ``path``. Raises :class:`TomlFileError` when it cannot be
    opened or read (no such file, a folder, no permission: "cannot read[ WHAT]: …"), is not
    UTF-8 text, as TOML must be (a binary file, another encoding: the offset of the first bad
    byte), or is not valid TOML (tomllib's line and column)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except (OSError, ValueError) as exc:  # ValueError: a NUL character in the path
        raise TomlFileError(path, f"cannot read{' ' + what if what else ''}: "
                                  f"{getattr(exc, 'strerror', None) or exc}") from exc
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise TomlFileError(path, f"not a TOML file: not UTF-8 text (byte 0x{data[exc.start]:02x} "
                                  f"at offset {exc.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise TomlFileError(path, f"not valid TOML: {exc}") from exc


#: the kinds of TOML file a user hands uvd, each told by a top-level key only it has, and what
#: each is for (a vehicle file holds [parameters] too: a file of [parameters] alone is either)
_KINDS = (
    ("configuration", ("loop", "sensors", "can", "control", "failsafe", "daemon"),
     "a daemon configuration (uvd run --config, uvd check-config)"),
    ("vehicle", ("thrusters", "thruster_defaults", "thrust_curves"),
     "a vehicle file (thrusters and the first guess: --vehicle, a configuration's [vehicle] "
     "name)"),
    ("profile", ("signals",), "a log profile (--profile)"),
    ("campaign", ("campaign", "axes"), "a campaign file (uvd campaign FILE)"),
    ("parameters", ("identified", "refused", "linear_damping"),
     "a parameter file (uvd identify --out; xval --params, identify --init, [estimation] "
     "initial_params)"),
)


def other_kind(doc: dict[str, Any], wanted: str) -> str | None:
    """What the TOML file ``doc`` is when it is plainly another kind of uvd's files than
    ``wanted`` ("configuration", "vehicle", "profile", "campaign" or "parameters"), e.g. "a
    vehicle file (…)"; None when it is that kind or none of them. For a loader's first error:
    a file handed to the wrong option otherwise fails on every one of its keys."""
    for kind, keys, said in _KINDS:
        if any(k in doc for k in keys):
            if kind == wanted:
                return None
            name = doc.get("vehicle", {}).get("name") if kind == "configuration" \
                and isinstance(doc.get("vehicle"), dict) else None
            return said + (f", of vehicle {name!r}" if isinstance(name, str) else "")
    return None


def refused_name(path: str | Path) -> str | None:
    """Why the system refuses to look ``path`` up at all (a name too long for the file
    system, a folder on the way without permission), else None — also when it is merely
    absent. A TOML file's name from a configuration is checked with it before ``is_file``,
    which raises for such a name on some Python versions and answers False on others."""
    try:
        os.stat(path)
    except OSError as exc:
        return None if exc.errno in _ABSENT else exc.strerror or str(exc)
    return None


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError("TOML has no NaN/inf here")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dump_toml(data: dict, _prefix: str = "") -> str:
    """TOML text of nested tables of scalars and arrays (what a uvd configuration holds)."""
    lines: list[str] = []
    tables = []
    for k, v in data.items():
        if isinstance(v, dict):
            tables.append((k, v))
        else:
            lines.append(f"{k} = {_toml_value(v)}")
    out = []
    if lines:
        if _prefix:
            out.append(f"[{_prefix}]")
        out.extend(lines)
        out.append("")
    for k, v in tables:
        out.append(dump_toml(v, f"{_prefix}.{k}" if _prefix else k))
    return "\n".join(out)
