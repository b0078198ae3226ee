"""TOML text of a configuration-like table: what the tools write for a daemon to read
(``sim-bridge``'s run configuration, the realtime replay's configuration of the daemon under
test). ``tomllib`` reads TOML but does not write it."""

from __future__ import annotations

import json
import math
from typing import Any

__all__ = ["dump_toml"]


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
