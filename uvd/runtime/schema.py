"""A small declarative configuration schema: frozen dataclasses whose fields carry metadata.

A configuration section is a frozen dataclass; each field is declared with :func:`setting`
(type from the annotation; unit, default, range, choices, documentation and whether it may
change on ``SIGHUP`` from the metadata) or :func:`section` (a nested table). The same
declaration drives three things, so they cannot drift apart:

* :func:`build` validates a parsed TOML mapping into the dataclass, collecting every problem as
  ``(dotted.key, reason)`` (unknown key, wrong type, out of range, not one of the choices,
  missing required key);
* :func:`describe` lists every key with its type, unit, default, range and doc — the source of
  the generated ``docs/config.md``;
* :func:`reloadable_changes` says which keys differ between two configurations and whether each
  may change while running.

A plain frozen dataclass without :func:`setting` metadata works too (documented only by its
type and default), which is how a driver's own configuration dataclass plugs in unchanged.
Cross-field rules go in an optional method ``_check(self, ctx) -> list[tuple[str, str]]``
returning ``(relative key, reason)`` pairs.

A lower layer's plain dataclass (drivers never import uvd) can be declared by a section of
this schema instead: :data:`DECLARED_BY` maps it to a dataclass of :func:`setting` fields,
which is built, validated and documented in its place and whose ``convert()`` returns the
plain dataclass.

Supported field types: ``bool``, ``int``, ``float`` (an integer is accepted), ``str``,
``pathlib.Path``, ``typing.Literal[...]`` (choices), ``X | None`` (absent means ``None``; TOML
has no null), ``tuple[T, ...]`` and fixed ``tuple[T, T]`` of the scalar types, :data:`PerAxis`
(one number or six, one per DOF), mappings (a free-form table), and nested dataclasses.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field
from pathlib import Path
from typing import Any, Literal, get_args, get_origin

__all__ = ["Meta", "setting", "section", "build", "describe", "KeyDoc", "BuildContext",
           "reloadable_changes", "as_dict", "DECLARED_BY", "PerAxis", "AXES", "with_values",
           "leaf_keys", "LeafKey"]

_META = "uvd.schema"

#: the six degrees of freedom in the order of v = [ν; ω] (thesis Appendix A)
AXES = ("surge", "sway", "heave", "roll", "pitch", "yaw")

#: a per-axis value: one number for all six DOF, or six in the order of :data:`AXES`
PerAxis = float | tuple[float, float, float, float, float, float]

#: ``plain dataclass -> the schema section declaring it``: where a configuration field has the
#: plain type, the section is built, validated and documented instead, and its ``convert()``
#: gives the value (the CAN driver's ``CanConfig`` is declared in uvd.runtime.config).
DECLARED_BY: dict[type, type] = {}


@dataclass(frozen=True)
class Meta:
    """Metadata of one configuration key.

    Attributes
    ----------
    unit : str
        Physical unit ("s", "Hz", "N/rad"…), empty for dimensionless values.
    doc : str
        One-sentence description (rendered in ``docs/config.md``).
    min, max : float or None
        Inclusive bounds (applied to every element of a tuple).
    gt : float or None
        Exclusive lower bound (``gt=0`` means strictly positive).
    choices : tuple or None
        Allowed values (``Literal`` annotations provide them automatically).
    length : int or None
        Exact length of a tuple value.
    reload : bool
        True when the key may change on ``SIGHUP`` without a restart.
    """

    unit: str = ""
    doc: str = ""
    min: float | None = None
    max: float | None = None
    gt: float | None = None
    choices: tuple | None = None
    length: int | None = None
    reload: bool = False


def setting(default: Any = MISSING, *, unit: str = "", doc: str = "", min: float | None = None,
            max: float | None = None, gt: float | None = None, choices: tuple | None = None,
            length: int | None = None, reload: bool = False) -> Any:
    """A configuration key: ``dataclasses.field`` with :class:`Meta`; no default = required."""
    meta = {_META: Meta(unit=unit, doc=doc, min=min, max=max, gt=gt, choices=choices,
                        length=length, reload=reload)}
    if isinstance(default, list):
        default = tuple(default)
    if isinstance(default, dict):  # a free-form table: each instance gets its own copy
        return field(default_factory=lambda d=dict(default): dict(d), metadata=meta)
    return field(default=default, metadata=meta)


def section(cls: type, *, doc: str = "") -> Any:
    """A nested table whose keys are the fields of the dataclass ``cls``."""
    return field(default_factory=cls, metadata={_META: Meta(doc=doc)})


@dataclass(frozen=True)
class BuildContext:
    """What a ``_check`` hook may need: the file being validated (for relative paths)."""

    source: Path | None = None

    @property
    def base_dir(self) -> Path:
        return self.source.parent if self.source is not None else Path.cwd()


def _meta(f: dataclasses.Field) -> Meta:
    return f.metadata.get(_META, Meta())


def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _is_optional(tp: Any) -> tuple[bool, Any]:
    if get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(get_args(tp)) == 2:
            return True, args[0]
    return False, tp


def type_name(tp: Any) -> str:
    """Human-readable name of a supported annotation (for messages and docs)."""
    if tp == PerAxis:
        return "number or list of 6 numbers"
    opt, inner = _is_optional(tp)
    if opt:
        return f"{type_name(inner)} (optional)"
    if get_origin(tp) is Literal:
        return "string" if all(isinstance(a, str) for a in get_args(tp)) else "choice"
    if get_origin(tp) is tuple:
        args = get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {type_name(args[0])}"
        return f"list of {len(args)} {type_name(args[0])}"
    if dataclasses.is_dataclass(tp) or _is_mapping(tp):
        return "table"
    return {bool: "boolean", int: "integer", float: "number", str: "string",
            Path: "path"}.get(tp, getattr(tp, "__name__", str(tp)))


def _is_mapping(tp: Any) -> bool:
    origin = get_origin(tp) or tp
    return origin in (dict, Mapping) or (isinstance(origin, type) and
                                         issubclass(origin, Mapping))


def _toml_type(value: Any) -> str:
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "number"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list | tuple):
        return "list"
    if isinstance(value, Mapping):
        return "table"
    return type(value).__name__


def _no_nul(value: str, key: str, errors: list) -> bool:
    """A string holds no NUL character (TOML's \\u0000): no path, port, address or name can
    (the operating system refuses it in a path, as a ValueError where an OSError is caught)."""
    if "\0" in value:
        errors.append((key, f"{value!r} holds a NUL character (\\u0000), which no path, port "
                            "or name can"))
        return False
    return True


def _scalar(value: Any, tp: Any, key: str, errors: list) -> Any:
    """Convert one TOML scalar to ``tp`` or record why not (returns MISSING on error)."""
    if get_origin(tp) is Literal:
        choices = get_args(tp)
        if value not in choices or isinstance(value, bool) != isinstance(choices[0], bool):
            errors.append((key, f"{value!r} is not one of {', '.join(map(repr, choices))}"))
            return MISSING
        return value
    if tp is bool:
        if not isinstance(value, bool):
            errors.append((key, f"expected a boolean (true/false), got {_toml_type(value)} "
                                f"{value!r}"))
            return MISSING
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            errors.append((key, f"expected an integer, got {_toml_type(value)} {value!r}"))
            return MISSING
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            errors.append((key, f"expected a number, got {_toml_type(value)} {value!r}"))
            return MISSING
        value = float(value)
        if not math.isfinite(value):  # no setting means "never" or "any" by an infinity
            errors.append((key, f"expected a finite number, got {value!r}"))
            return MISSING
        return value
    if tp is Path:
        if not isinstance(value, str) or not value:
            errors.append((key, f"expected a file path (string), got {_toml_type(value)} "
                                f"{value!r}"))
            return MISSING
        return Path(value) if _no_nul(value, key, errors) else MISSING
    if tp is str:
        if not isinstance(value, str):
            errors.append((key, f"expected a string, got {_toml_type(value)} {value!r}"))
            return MISSING
        return value if _no_nul(value, key, errors) else MISSING
    raise TypeError(f"unsupported configuration type {tp!r} for {key}")


def _range(value: Any, meta: Meta, key: str, errors: list) -> bool:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return True
    bad = ((meta.min is not None and value < meta.min)
           or (meta.max is not None and value > meta.max)
           or (meta.gt is not None and value <= meta.gt))
    if bad:
        errors.append((key, f"{value!r} is out of range (must be {range_text(meta)})"))
        return False
    return True


def range_text(meta: Meta) -> str:
    """The bounds of ``meta`` as text (``> 0 and ≤ 2000``), empty when unbounded."""
    parts = []
    if meta.gt is not None:
        parts.append(f"> {meta.gt:g}")
    if meta.min is not None:
        parts.append(f"≥ {meta.min:g}")
    if meta.max is not None:
        parts.append(f"≤ {meta.max:g}")
    return " and ".join(parts)


def _value(value: Any, tp: Any, meta: Meta, key: str, errors: list, ctx: BuildContext) -> Any:
    if tp == PerAxis:
        if isinstance(value, list | tuple) and len(value) != len(AXES):
            errors.append((key, f"expected one number or {len(AXES)} ({', '.join(AXES)}), "
                                f"got {len(value)} values"))
            return MISSING
        tp = get_args(PerAxis)[1] if isinstance(value, list | tuple) else float
    opt, tp = _is_optional(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            errors.append((key, f"expected a table [{key}], got {_toml_type(value)} {value!r}"))
            return MISSING
        declared = DECLARED_BY.get(tp)
        if declared is not None:
            sec = _build(declared, value, key, errors, ctx)
            return MISSING if sec is MISSING else sec.convert()
        return _build(tp, value, key, errors, ctx)
    if _is_mapping(tp):
        if not isinstance(value, Mapping):
            errors.append((key, f"expected a table, got {_toml_type(value)} {value!r}"))
            return MISSING
        return dict(value)
    if get_origin(tp) is tuple:
        args = get_args(tp)
        elem = args[0]
        if not (len(args) == 2 and args[1] is Ellipsis) and isinstance(value, list | tuple) \
                and len(value) != len(args):
            errors.append((key, f"expected exactly {len(args)} values, got {len(value)}"))
            return MISSING
        if not isinstance(value, list | tuple):
            errors.append((key, f"expected a list of {type_name(elem)}, got "
                                f"{_toml_type(value)} {value!r}"))
            return MISSING
        if meta.length is not None and len(value) != meta.length:
            errors.append((key, f"expected exactly {meta.length} values, got {len(value)}"))
            return MISSING
        out = []
        n_err = len(errors)
        for i, v in enumerate(value):
            conv = _scalar(v, elem, f"{key}[{i}]", errors)
            if conv is not MISSING:
                _range(conv, meta, f"{key}[{i}]", errors)
                if meta.choices is not None and conv not in meta.choices:
                    errors.append((f"{key}[{i}]", f"{conv!r} is not one of "
                                                  f"{', '.join(map(repr, meta.choices))}"))
            out.append(conv)
        return tuple(out) if len(errors) == n_err else MISSING
    conv = _scalar(value, tp, key, errors)
    if conv is MISSING:
        return MISSING
    if not _range(conv, meta, key, errors):
        return MISSING
    if meta.choices is not None and conv not in meta.choices:
        errors.append((key, f"{conv!r} is not one of {', '.join(map(repr, meta.choices))}"))
        return MISSING
    return conv


def _refusal(prefix: str, cls: type, exc: Exception) -> tuple[str, str]:
    """The key and reason of a dataclass's own refusal (a driver's ``__post_init__``): a
    message ``"Cls.field must …"`` names the key ``prefix.field``; any other names the table."""
    text = str(exc)
    m = re.match(rf"{cls.__name__}\.(\w+) (.+)", text, re.S)
    if m and m[1] in {f.name for f in dataclasses.fields(cls)}:
        return (f"{prefix}.{m[1]}" if prefix else m[1]), m[2]
    return prefix or cls.__name__, text


def _build(cls: type, data: Mapping[str, Any], prefix: str, errors: list,
           ctx: BuildContext) -> Any:
    hints = _hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    dot = f"{prefix}." if prefix else ""
    for k in data:
        if k not in fields:
            known = ", ".join(sorted(fields)) or "none"
            errors.append((f"{dot}{k}", f"unknown key (known keys here: {known})"))
    kwargs: dict[str, Any] = {}
    n_err = len(errors)
    for name, f in fields.items():
        key = f"{dot}{name}"
        tp = hints[name]
        meta = _meta(f)
        if name in data:
            v = _value(data[name], tp, meta, key, errors, ctx)
            if v is not MISSING:
                kwargs[name] = v
        elif dataclasses.is_dataclass(_is_optional(tp)[1]) and not _is_optional(tp)[0]:
            # a missing table is an empty one: its own required keys are reported inside it
            v = _value({}, tp, meta, key, errors, ctx)
            if v is not MISSING:
                kwargs[name] = v
        elif f.default is MISSING and f.default_factory is MISSING:
            if _is_optional(tp)[0]:
                kwargs[name] = None
            else:
                errors.append((key, f"missing required key ({type_name(tp)}"
                                    f"{', ' + meta.doc if meta.doc else ''})"))
    if len(errors) != n_err:
        return MISSING
    try:
        obj = cls(**kwargs)
    except (ValueError, TypeError) as exc:  # the dataclass's own __post_init__ refused
        errors.append(_refusal(prefix, cls, exc))
        return MISSING
    check = getattr(obj, "_check", None)
    if callable(check):
        for rel, reason in check(ctx):
            errors.append((f"{dot}{rel}" if rel else prefix, reason))
        if len(errors) != n_err:
            return MISSING
    return obj


def build(cls: type, data: Mapping[str, Any], *, ctx: BuildContext | None = None,
          prefix: str = "") -> tuple[Any, list[tuple[str, str]]]:
    """Validate ``data`` into an instance of ``cls``.

    Returns
    -------
    obj : cls instance or None
        None when there was any error.
    errors : list of (str, str)
        ``(dotted.key, reason)`` for every problem found (all of them, not only the first).
    """
    errors: list[tuple[str, str]] = []
    obj = _build(cls, data, prefix, errors, ctx or BuildContext())
    return (None if obj is MISSING or errors else obj), errors


@dataclass(frozen=True)
class KeyDoc:
    """One documented key (see :func:`describe`)."""

    key: str
    type: str
    unit: str
    default: str
    constraint: str
    reload: bool
    doc: str


def _fmt_value(d: Any) -> str:
    if d is None:
        return "(none)"
    if isinstance(d, bool):
        return "true" if d else "false"
    if isinstance(d, str):
        return f'"{d}"'
    if isinstance(d, Path):
        try:
            rel = d.resolve().relative_to(Path(__file__).resolve().parents[2])
            return f'"{rel}"'
        except ValueError:
            return f'"{d}"'
    if isinstance(d, float):
        return "inf" if math.isinf(d) else f"{d:g}"
    if isinstance(d, tuple | list):
        return "[" + ", ".join(_fmt_value(x) for x in d) + "]"
    if isinstance(d, Mapping):
        return "{}" if not d else "{" + ", ".join(f"{k} = {_fmt_value(v)}"
                                                  for k, v in d.items()) + "}"
    return str(d)


_NUMPYDOC_SECTION = re.compile(r"^\s*(Attributes|Parameters)\s*\n\s*-{3,}\s*$", re.M)
_NUMPYDOC_ITEM = re.compile(r"^(?P<indent>\s*)(?P<names>[A-Za-z_][\w]*(?:\s*,\s*[A-Za-z_][\w]*)*)"
                            r"\s*:\s*(?P<type>.*)$")


def numpydoc_attributes(cls: type) -> dict[str, str]:
    """Descriptions of the names in a class docstring's ``Attributes``/``Parameters`` section."""
    doc = cls.__doc__ or ""
    m = _NUMPYDOC_SECTION.search(doc)
    if not m:
        return {}
    out: dict[str, str] = {}
    current: list[str] = []
    item_indent = None
    for line in doc[m.end():].splitlines():
        if not line.strip():
            continue
        indent = len(line) - len(line.lstrip())
        im = _NUMPYDOC_ITEM.match(line)
        if im and (item_indent is None or indent <= item_indent):
            if re.match(r"^\s*-{3,}\s*$", line):
                break
            item_indent = indent
            current = [n.strip() for n in im.group("names").split(",")]
            for n in current:
                out.setdefault(n, "")
            continue
        if item_indent is not None and indent <= item_indent:
            break  # next section
        for n in current:
            out[n] = (out[n] + " " + line.strip()).strip()
    return out


def _fmt_default(f: dataclasses.Field, tp: Any) -> str:
    if f.default is not MISSING:
        return _fmt_value(f.default)
    if f.default_factory is not MISSING:
        try:
            d = f.default_factory()
        except Exception:  # a factory that needs arguments: nothing to show
            return ""
        return "" if dataclasses.is_dataclass(d) else _fmt_value(d)
    return "**required**"


def describe(cls: type, prefix: str = "") -> list[tuple[str, str, list[KeyDoc]]]:
    """Every table of ``cls`` as ``(dotted table name, table doc, [KeyDoc, …])``, depth first."""
    if cls in DECLARED_BY:
        return describe(DECLARED_BY[cls], prefix)
    hints = _hints(cls)
    own: list[KeyDoc] = []
    nested: list[tuple[str, str, list[KeyDoc]]] = []
    doc = (cls.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
    npdoc = numpydoc_attributes(cls)
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        tp = hints[f.name]
        key = f"{prefix}.{f.name}" if prefix else f.name
        meta = _meta(f)
        inner = _is_optional(tp)[1]
        if dataclasses.is_dataclass(inner):
            nested.extend(describe(inner, key))
            continue
        choices = meta.choices
        if get_origin(inner) is Literal:
            choices = get_args(inner)
        elif get_origin(inner) is tuple and get_origin(get_args(inner)[0]) is Literal:
            choices = get_args(get_args(inner)[0])
        cons = range_text(meta)
        if choices:
            cons = "one of " + ", ".join(f"`{c}`" for c in choices)
        if meta.length is not None:
            cons = (cons + "; " if cons else "") + f"exactly {meta.length} values"
        own.append(KeyDoc(key=key, type=type_name(tp), unit=meta.unit,
                          default=_fmt_default(f, tp), constraint=cons, reload=meta.reload,
                          doc=meta.doc or npdoc.get(f.name, "")))
    out = [(prefix, doc, own)] if own else []
    return out + nested


def as_dict(obj: Any) -> Any:
    """A configuration object as plain nested dicts/lists (for printing and JSON)."""
    if dataclasses.is_dataclass(obj):
        return {f.name: as_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                if f.init}
    if isinstance(obj, tuple):
        return [as_dict(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def reloadable_changes(old: Any, new: Any, prefix: str = ""
                       ) -> tuple[Any, list[str], list[str]]:
    """Merge the keys of ``new`` that may change at run time into ``old``.

    Returns
    -------
    merged : same type as ``old``
        ``old`` with every changed reloadable key taken from ``new``.
    applied : list of str
        Dotted keys that changed and were taken.
    refused : list of str
        Dotted keys that changed but need a restart (kept at their old value).
    """
    applied: list[str] = []
    refused: list[str] = []
    changes: dict[str, Any] = {}
    for f in dataclasses.fields(old):
        if not f.init:
            continue
        key = f"{prefix}.{f.name}" if prefix else f.name
        a, b = getattr(old, f.name), getattr(new, f.name)
        if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b) and type(a) is type(b):
            merged, ap, rf = reloadable_changes(a, b, key)
            applied += ap
            refused += rf
            if ap:
                changes[f.name] = merged
        elif a != b:
            if _meta(f).reload:
                applied.append(key)
                changes[f.name] = b
            else:
                refused.append(key)
    if not changes:
        return old, applied, refused
    merged = dataclasses.replace(old, **changes)
    for f in dataclasses.fields(old):  # carry non-init fields (e.g. the file name) over
        if not f.init:
            object.__setattr__(merged, f.name, getattr(old, f.name))
    return merged, applied, refused


@dataclass(frozen=True)
class LeafKey:
    """One key of a section as :func:`leaf_keys` lists it: dotted name, type, metadata and
    default."""

    key: str
    type: Any
    meta: Meta
    default: Any


def leaf_keys(cls: type, prefix: str = "") -> list[LeafKey]:
    """Every non-table key of ``cls`` (nested tables flattened), in declaration order."""
    if cls in DECLARED_BY:
        return leaf_keys(DECLARED_BY[cls], prefix)
    hints = _hints(cls)
    out: list[LeafKey] = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        key = f"{prefix}.{f.name}" if prefix else f.name
        inner = _is_optional(hints[f.name])[1]
        if dataclasses.is_dataclass(inner):
            out += leaf_keys(inner, key)
            continue
        default = f.default if f.default is not MISSING else (
            f.default_factory() if f.default_factory is not MISSING else None)
        out.append(LeafKey(key, hints[f.name], _meta(f), default))
    return out


def with_values(obj: Any, values: Mapping[str, Any], *, reload_only: bool = False,
                ctx: BuildContext | None = None) -> tuple[Any, list[tuple[str, str]]]:
    """``obj`` with dotted keys replaced, each value validated as :func:`build` validates it
    (type, range, choices; a section's ``_check`` runs again).

    Parameters
    ----------
    obj : dataclass instance
        A configuration (or section).
    values : mapping
        ``{"control.kp": 350.0, …}``.
    reload_only : bool
        Refuse keys that may not change while running (not marked *reload*).
    ctx : BuildContext, optional
        For the sections' checks; by default the folder of ``obj.source`` (a Config's file).

    Returns
    -------
    new : same type as ``obj``
        ``obj`` itself when there are errors.
    errors : list of (key, reason)
        Unknown keys, keys that need a restart, bad values — every one named.
    """
    if ctx is None:  # relative paths as the file they came from says (a Config's source)
        src = getattr(obj, "source", None)
        ctx = BuildContext(Path(src) if src else None)
    errors: list[tuple[str, str]] = []
    new = _with(obj, dict(values), "", errors, reload_only, ctx)
    return (obj, errors) if errors else (new, errors)


def _with(obj: Any, values: dict[str, Any], prefix: str, errors: list, reload_only: bool,
          ctx: BuildContext) -> Any:
    cls = type(obj)
    hints = _hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    groups: dict[str, dict[str, Any]] = {}
    for k, v in values.items():
        head, _, rest = k.partition(".")
        groups.setdefault(head, {})[rest] = v
    changes: dict[str, Any] = {}
    n_err = len(errors)
    for head, sub in groups.items():
        key = f"{prefix}.{head}" if prefix else head
        f = fields.get(head)
        if f is None:
            errors.append((key, "unknown key"))
            continue
        cur = getattr(obj, head)
        if dataclasses.is_dataclass(cur) and type(cur) not in DECLARED_BY:
            if "" in sub:
                errors.append((key, "is a table, not a key"))
                continue
            changes[head] = _with(cur, sub, key, errors, reload_only, ctx)
            continue
        if set(sub) != {""}:
            why = "set in the configuration file only (a driver's table)" \
                if dataclasses.is_dataclass(cur) else "not a table"
            errors += [(f"{key}.{rest}" if rest else key, why) for rest in sub]
            continue
        meta = _meta(f)
        if reload_only and not meta.reload:
            errors.append((key, "cannot change while running (needs a restart)"))
            continue
        conv = _value(sub[""], hints[head], meta, key, errors, ctx)
        if conv is not MISSING:
            changes[head] = conv
    if len(errors) != n_err or not changes:
        return obj
    try:
        new = dataclasses.replace(obj, **changes)
    except (ValueError, TypeError) as exc:  # the dataclass's own __post_init__ refused (_build)
        errors.append(_refusal(prefix, cls, exc))
        return obj
    for f in dataclasses.fields(cls):  # carry non-init fields (e.g. the file name) over
        if not f.init:
            object.__setattr__(new, f.name, getattr(obj, f.name))
    check = getattr(new, "_check", None)
    if check is not None and prefix:  # the whole Config's check loads the vehicle: not here
        errors += [(f"{prefix}.{k}", r) for k, r in check(ctx)]
    return new
