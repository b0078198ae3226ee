"""Parameter files: a ``[parameters]`` TOML table holding θ_UV (2.48) in the full form
(M, D1…D6, g, b) or the decoupled form (m, d, g, b) of §5.3.1.

:func:`params_to_toml` / :func:`save_params` write the full form (atomically);
:func:`params_from_toml` reads either; :func:`params_from_mapping` builds the parameters from
an already parsed table (the ``[parameters]`` of a vehicle file, :mod:`uvd.io.vehicle`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from uvd.errors import ParameterError
from uvd.io.toml import TomlFileError, other_kind, read_toml
from uvd.jsonio import write_whole
from uvd.model.params import UVParams


def params_to_toml(p: UVParams, *, title: str = "") -> str:
    """TOML text of a parameter set, loadable by :func:`params_from_toml`."""

    def row(xs) -> str:
        return "[" + ", ".join(repr(float(x)) for x in xs) + "]"

    def mat(A) -> str:
        return "[\n" + "".join(f"  {row(r)},\n" for r in A) + "]"

    lines = []
    if title:
        lines.append(f"# {title}")
    lines.append("[parameters]")
    lines.append(f"g = {float(p.g)!r}")
    lines.append(f"b = {row(p.b)}")
    lines.append(f"M = {mat(p.M)}")
    for i, Di in enumerate(p.D, start=1):
        lines.append(f"D{i} = {mat(Di)}")
    return "\n".join(lines) + "\n"


def _numbers(table: dict, key: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    """``table[key]`` as a float array of ``shape`` (``()``: one number), every entry an int or
    a float (a boolean or a text is not a number) and finite; else a ParameterError naming the
    key."""
    what = ("a number" if shape == () else f"{shape[0]} numbers" if len(shape) == 1
            else f"a {shape[0]} × {shape[1]} matrix of numbers")
    value = table[key]
    stack, bad = [value], None
    while stack and bad is None:
        v = stack.pop()
        if isinstance(v, list):
            stack.extend(v)
        elif isinstance(v, bool) or not isinstance(v, (int, float)):
            bad = v
    if bad is not None:
        raise ParameterError(f"{where}: {key} must be {what}; it holds {bad!r}")
    try:
        arr = np.array(value, dtype=float)
    except ValueError:  # ragged rows
        raise ParameterError(f"{where}: {key} must be {what}; its rows differ in length") \
            from None
    if arr.shape != shape:
        raise ParameterError(f"{where}: {key} must be {what}; got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{where}: {key} has a non-finite entry")
    return arr


def params_from_mapping(table: dict, *, where: str = "parameters") -> UVParams:
    """Build parameters from a TOML table in either the full form (M, D1…D6, g, b) or the
    decoupled form (m, d, g, b) of §5.3.1. Unknown or missing keys, an entry that is not a
    finite number, a wrong shape and an M that is not symmetric (the mass matrix of (2.40)
    is) are errors naming the key."""
    if not isinstance(table, dict):
        raise ParameterError(f"{where}: expected a table, got {type(table).__name__} "
                             f"{table!r:.80}")
    full = {"M", "D1", "D2", "D3", "D4", "D5", "D6", "g", "b"}
    dec = {"m", "d", "g", "b"}
    keys = set(table)
    if "M" in keys:
        unknown = keys - full
        if unknown:
            raise ParameterError(f"{where}: unknown key(s) {sorted(unknown)}")
        missing = full - keys
        if missing:
            raise ParameterError(f"{where}: missing key(s) {sorted(missing)}")
        M = _numbers(table, "M", (6, 6), where)
        D = np.stack([_numbers(table, f"D{i}", (6, 6), where) for i in range(1, 7)])
        g = float(_numbers(table, "g", (), where))
        b = _numbers(table, "b", (3,), where)
        asym = float(np.max(np.abs(M - M.T)))
        if asym > 1e-9 * max(1.0, float(np.max(np.abs(M)))):
            raise ParameterError(f"{where}: M is not symmetric (max |M - Mᵀ| = {asym:.3g}); "
                                 "the mass matrix of (2.40) is")
        return UVParams(M=M, D=D, g=g, b=b)
    unknown = keys - dec
    if unknown:
        raise ParameterError(f"{where}: unknown key(s) {sorted(unknown)}")
    missing = dec - keys
    if missing:
        raise ParameterError(f"{where}: missing key(s) {sorted(missing)} "
                             "(give M, D1..D6, g, b or m, d, g, b)")
    m, d = _numbers(table, "m", (6,), where), _numbers(table, "d", (6,), where)
    g = float(_numbers(table, "g", (), where))
    return UVParams.decoupled(m, d, g, _numbers(table, "b", (3,), where))


def params_from_toml(path: str | Path) -> UVParams:
    """Load a ``[parameters]`` TOML (:func:`params_to_toml`'s layout or the decoupled form).

    Raises :class:`~uvd.errors.ParameterError` naming the file: unreadable, not TOML, no
    ``[parameters]`` table, a missing or unknown key, a wrong shape or a non-finite entry.
    """
    path = Path(path)
    try:
        doc = read_toml(path, "parameters")
    except TomlFileError as exc:
        raise ParameterError(str(exc)) from exc
    if "parameters" not in doc:
        kind = other_kind(doc, "parameters")
        raise ParameterError(f"{path}: " + (f"this is {kind}, not a parameter file" if kind
                                            else "no [parameters] table"))
    return params_from_mapping(doc["parameters"], where=f"{path}: [parameters]")


def save_params(p: UVParams, path: str | Path, *, title: str = "", extra: str = "") -> None:
    """Write :func:`params_to_toml` to ``path`` atomically.

    The text goes to a temporary file in the same folder, is flushed to disk and renamed over
    ``path`` (:func:`uvd.jsonio.write_whole`): a reader (or a crash mid-write) sees the old file
    or the new one, never half; a write that fails (a full disk) leaves the old file and no
    temporary one, and its OSError names ``path``.
    ``extra``: further TOML tables after ``[parameters]`` (e.g. what was identified).
    """
    path = Path(path)
    text = params_to_toml(p, title=title) + extra
    tmp = path.with_name(f".{path.name}.tmp")

    def write(tmp: Path) -> None:
        with tmp.open("w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())

    write_whole(path, write, tmp)


def linear_damping_toml(diag, comment: str) -> str:
    """The ``[linear_damping]`` table :func:`linear_damping_from_toml` reads, as TOML text
    (a leading blank line, then ``# comment`` and ``rotational = [K_p, M_q, N_r]``)."""
    values = ", ".join(repr(float(x)) for x in diag)
    return f"\n[linear_damping]\n# {comment}\nrotational = [{values}]\n"


def linear_damping_from_toml(path: str | Path):
    """The optional ``[linear_damping]`` table of a parameter file: ``rotational = [K_p, M_q,
    N_r]`` (N m s/rad, negative = dissipative) — the linear term of a published model that
    (2.40) does not have (:func:`uvd.estimation.xval.rot_from_lumped`) — as a 3 × 3 diagonal,
    or None."""
    path = Path(path)
    try:
        doc = read_toml(path, "parameters")
    except TomlFileError as exc:
        raise ParameterError(str(exc)) from exc
    tbl = doc.get("linear_damping")
    if tbl is None:
        return None
    bad = set(tbl) - {"rotational"}
    if bad or "rotational" not in tbl:
        raise ParameterError(f"{path}: [linear_damping] takes one key, rotational = [K_p, M_q, "
                             f"N_r]; got {sorted(tbl)}")
    d = np.asarray(tbl["rotational"], dtype=float)
    if d.shape != (3,) or not np.all(np.isfinite(d)):
        raise ParameterError(f"{path}: [linear_damping] rotational must be 3 finite numbers")
    if np.any(d > 0):
        raise ParameterError(f"{path}: [linear_damping] rotational must be <= 0 (dissipative)")
    return np.diag(d)
