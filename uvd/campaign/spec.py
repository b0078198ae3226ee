"""A campaign file (``uvd campaign SPEC.toml``): what to run, validated into frozen values.

::

    [campaign]
    name = "fdc-detection"
    kind = "fdc"                 # the run function (uvd.campaign.runs.KINDS)
    sampling = "random"          # "grid": the product of the list axes; "random": ``runs`` draws
    runs = 300
    seed = 0                     # of the draws (run i draws from default_rng([seed, i]))

    [axes]
    vehicle = ["jhu-rov", "bluerov2-heavy"]        # a list: a grid axis, or a uniform choice
    seed = {integers = [0, 1000000]}               # random only: an integer in [a, b)
    onset_min = {uniform = [30.0, 50.0]}           # random only: a float in [a, b)
    delta = {uniform = [5.0, 40.0], signed = true} # ± a magnitude in [a, b)
    after_min = 20.0                               # a constant
    fault = ["thruster", "drag", "mass", "buoyancy"]
    fault_size = {by = "fault", thruster = {uniform = [0.0, 0.8]}, drag = 1.5, ...}

An axis given ``by`` another takes the value (or draw) named by that axis's value in the same
run. Every axis is checked against the kind's own list of axes (name, type, allowed values,
range — in every run, as a draw may leave it in some only); a missing one takes the kind's
default. Errors name the file, the key and the reason
(:class:`CampaignError`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uvd.errors import UvdError
from uvd.io.toml import TomlFileError, other_kind, read_toml

SAMPLINGS = ("grid", "random")
DRAWS = ("uniform", "integers")
#: the most runs one campaign may hold (its runs are listed when it is read): a typing slip
#: such as ``runs = 10000000000`` is refused by name instead of filling the memory
MAX_RUNS = 100_000
#: the range of an integer draw (numpy's int64)
_INT64 = (-2 ** 63, 2 ** 63)


class CampaignError(UvdError, ValueError):
    """A campaign file or value is invalid; the message names the file, key and reason."""


#: what is wrong with one axis's value in a run (None: nothing), given the run's inputs (a
#: fault's size depends on its kind)
Check = Callable[[Any, Mapping[str, Any]], str | None]


@dataclass(frozen=True)
class Axis:
    """One input of a run function: its type (``float``, ``int``, ``str``), default, the
    values a ``str`` axis may take (None: any), and ``check``: what a value must be beyond
    its type (e.g. :func:`within`), checked in every run when the file is read."""

    type: type
    default: Any
    choices: tuple[str, ...] | None = None
    doc: str = ""
    check: Check | None = None


def within(lo: float | None = None, hi: float | None = None, *, above: bool = False) -> Check:
    """The check that a number lies in [lo, hi] — (lo, hi] when ``above`` — either end
    None: unbounded."""
    if lo is not None and hi is not None:
        text = f"in {'(' if above else '['}{lo:g}, {hi:g}]"
    elif lo is not None:
        text = f"{'>' if above else '≥'} {lo:g}"
    else:
        text = f"≤ {hi:g}"

    def check(x: Any, run: Mapping[str, Any]) -> str | None:
        low = lo is not None and (x <= lo if above else x < lo)
        return f"must be {text}" if low or (hi is not None and x > hi) else None
    return check


@dataclass(frozen=True)
class CampaignSpec:
    """A validated campaign: ``runs`` is the list of every run's inputs (one dict per run, in
    run order, every axis of the kind present)."""

    name: str
    kind: str
    sampling: str
    seed: int
    description: str
    runs: tuple[dict, ...]
    source: str = ""


def _where(source: str, key: str) -> str:
    return f"{source}: {key}" if source else key


def _check_value(kind_axes: dict[str, Axis], name: str, value: Any, where: str) -> Any:
    ax = kind_axes[name]
    if ax.type is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise CampaignError(f"{where}: {value!r} is not a number")
        value = float(value)
        if not math.isfinite(value):
            raise CampaignError(f"{where}: {value!r} is not finite")
    elif ax.type is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise CampaignError(f"{where}: {value!r} is not an integer")
    elif ax.type is str:
        if not isinstance(value, str):
            raise CampaignError(f"{where}: {value!r} is not a string")
        if ax.choices is not None and value not in ax.choices:
            raise CampaignError(f"{where}: {value!r} is not one of {', '.join(ax.choices)}")
    return value


def _parse_values(kind_axes, name: str, raw: Any, sampling: str, where: str):
    """One axis value: ("const", v), ("list", [v…]), ("uniform"/"integers", (a, b))."""
    if isinstance(raw, list):
        if not raw:
            raise CampaignError(f"{where}: an empty list")
        return ("list", [_check_value(kind_axes, name, v, f"{where}[{i}]")
                         for i, v in enumerate(raw)])
    if isinstance(raw, dict):
        keys = set(raw)
        draw = keys & set(DRAWS)
        signed = raw.get("signed", False)
        if len(draw) != 1 or keys - draw - {"signed"} or not isinstance(signed, bool):
            raise CampaignError(f"{where}: a table must be {{uniform = [a, b]}} or "
                                f"{{integers = [a, b]}}, optionally with signed = true "
                                f"(got {raw!r})")
        how = draw.pop()
        if sampling != "random":
            raise CampaignError(f"{where}: {how} draws need sampling = \"random\" (a grid "
                                "takes lists)")
        ab = raw[how]
        if not (isinstance(ab, list) and len(ab) == 2):
            raise CampaignError(f"{where}.{how}: give [a, b]")
        want = int if how == "integers" else float
        if kind_axes[name].type not in (want, float) or (how == "uniform"
                                                         and kind_axes[name].type is not float):
            raise CampaignError(f"{where}: {how} draws do not fit this "
                                f"{kind_axes[name].type.__name__} axis")
        a, b = (_check_value({name: Axis(want, None)}, name, v, f"{where}.{how}[{i}]")
                for i, v in enumerate(ab))
        if not a < b:
            raise CampaignError(f"{where}.{how}: need a < b (got {a}, {b})")
        if how == "integers" and not (_INT64[0] <= a and b <= _INT64[1]):
            raise CampaignError(f"{where}.{how}: the bounds must lie within ±2⁶³ "
                                f"(got {a}, {b})")
        if how == "uniform" and not math.isfinite(b - a):
            raise CampaignError(f"{where}.{how}: b − a must be a finite number (got {a}, {b})")
        if signed and not (how == "uniform" and a >= 0):
            raise CampaignError(f"{where}.signed: needs a uniform draw of a magnitude (a ≥ 0)")
        return ("signed" if signed else how, (a, b))
    return ("const", _check_value(kind_axes, name, raw, where))


def _draw(parsed, rng: np.random.Generator):
    how, v = parsed
    if how == "const":
        return v
    if how == "list":
        return v[int(rng.integers(len(v)))]
    if how == "integers":
        return int(rng.integers(v[0], v[1]))
    x = float(rng.uniform(v[0], v[1]))
    if how == "signed":
        x = x if rng.integers(2) else -x
    return x


def parse(data: dict, kinds: dict[str, dict[str, Axis]], source: str = "") -> CampaignSpec:
    """Validate a campaign's tables (``tomllib`` output) into a :class:`CampaignSpec`."""
    unknown = set(data) - {"campaign", "axes"}
    kind = other_kind(data, "campaign") if unknown else None
    if kind:
        raise CampaignError(f"{source or '<campaign>'}: this is {kind}, not a campaign file")
    if unknown:
        raise CampaignError(f"{_where(source, sorted(unknown)[0])}: unknown table; known: "
                            "[campaign], [axes]")
    head = data.get("campaign")
    if head is None:
        raise CampaignError(f"{_where(source, '[campaign]')}: missing")
    if not isinstance(head, dict):
        raise CampaignError(f"{_where(source, '[campaign]')}: must be a table, got "
                            f"{type(head).__name__} {head!r:.80}")
    known_head = {"name", "kind", "sampling", "runs", "seed", "description"}
    for k in head:
        if k not in known_head:
            raise CampaignError(f"{_where(source, f'campaign.{k}')}: unknown key; known: "
                                f"{', '.join(sorted(known_head))}")
    name = head.get("name")
    if not isinstance(name, str) or not name:
        raise CampaignError(f"{_where(source, 'campaign.name')}: a non-empty string is needed")
    kind = head.get("kind")
    if not isinstance(kind, str) or kind not in kinds:
        raise CampaignError(f"{_where(source, 'campaign.kind')}: {kind!r} is not one of "
                            f"{', '.join(sorted(kinds))}")
    sampling = head.get("sampling", "grid")
    if not isinstance(sampling, str) or sampling not in SAMPLINGS:
        raise CampaignError(f"{_where(source, 'campaign.sampling')}: {sampling!r} is not one "
                            f"of {', '.join(SAMPLINGS)}")
    seed = head.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise CampaignError(f"{_where(source, 'campaign.seed')}: a non-negative integer is "
                            "needed")
    n_runs = head.get("runs")
    if sampling == "random":
        if isinstance(n_runs, bool) or not isinstance(n_runs, int) or n_runs < 1:
            raise CampaignError(f"{_where(source, 'campaign.runs')}: random sampling needs "
                                "a positive integer count of runs")
        if n_runs > MAX_RUNS:
            raise CampaignError(f"{_where(source, 'campaign.runs')}: {n_runs} runs; a "
                                f"campaign holds at most {MAX_RUNS} (split it)")
    elif n_runs is not None:
        raise CampaignError(f"{_where(source, 'campaign.runs')}: a grid's count is the "
                            "product of its lists; remove runs or use sampling = \"random\"")
    description = head.get("description", "")
    if not isinstance(description, str):
        raise CampaignError(f"{_where(source, 'campaign.description')}: a string is needed")
    kind_axes = kinds[kind]
    axes_raw = data.get("axes", {})
    if not isinstance(axes_raw, dict):
        raise CampaignError(f"{_where(source, '[axes]')}: must be a table")
    parsed: dict[str, Any] = {}
    for ax, raw in axes_raw.items():
        where = _where(source, f"axes.{ax}")
        if ax not in kind_axes:
            raise CampaignError(f"{where}: unknown axis of kind {kind!r}; known: "
                                f"{', '.join(sorted(kind_axes))}")
        if isinstance(raw, dict) and "by" in raw:
            by = raw["by"]
            if not isinstance(by, str) or by not in axes_raw or by == ax or (
                    isinstance(axes_raw[by], dict) and "by" in axes_raw[by]):
                raise CampaignError(f"{where}.by: {by!r} is not another plain axis of this "
                                    "campaign")
            choices = kind_axes[by].choices if by in kind_axes else None
            stray = sorted(k for k in raw if k != "by" and choices is not None
                           and k not in choices)
            if stray:  # a misspelt case, whose value would never be used
                raise CampaignError(f"{where}.{stray[0]}: {by} never takes this value; it "
                                    f"takes {', '.join(choices)}")
            cases = {k: _parse_values(kind_axes, ax, v, sampling, f"{where}.{k}")
                     for k, v in raw.items() if k != "by"}
            parsed[ax] = ("by", by, cases)
        else:
            parsed[ax] = _parse_values(kind_axes, ax, raw, sampling, where)
    runs = _expand(parsed, kind_axes, sampling, seed, n_runs, source)
    return CampaignSpec(name=name, kind=kind, sampling=sampling, seed=seed,
                        description=description, runs=tuple(runs), source=source)


def _resolve_by(parsed, run: dict, rng, source: str, grid: bool) -> None:
    for ax, p in parsed.items():
        if p[0] != "by":
            continue
        _, by, cases = p
        key = str(run[by])
        if key not in cases:
            raise CampaignError(f"{_where(source, f'axes.{ax}')}: no case for {by} = {key!r}")
        case = cases[key]
        if grid and case[0] == "list":
            raise CampaignError(f"{_where(source, f'axes.{ax}.{key}')}: a grid takes one "
                                "value per case")
        run[ax] = _draw(case, rng)


def _check_run(kind_axes: dict[str, Axis], run: dict, i: int, source: str) -> None:
    """Refuse a run whose value of an axis fails the axis's check, naming the axis, the value
    and the run (a draw may leave the range in some runs only)."""
    for name, ax in kind_axes.items():
        if ax.check is not None and (why := ax.check(run[name], run)) is not None:
            raise CampaignError(f"{_where(source, f'axes.{name}')}: {run[name]!r} {why} "
                                f"(run {i})")


def _expand(parsed, kind_axes, sampling: str, seed: int, n_runs: int | None,
            source: str) -> list[dict]:
    defaults = {k: a.default for k, a in kind_axes.items()}
    plain = {k: p for k, p in parsed.items() if p[0] != "by"}
    runs = []
    if sampling == "grid":
        names = sorted(plain)
        lists = [plain[k][1] if plain[k][0] == "list" else [plain[k][1]] for k in names]
        n_grid = math.prod(len(v) for v in lists)
        if n_grid > MAX_RUNS:
            raise CampaignError(f"{_where(source, '[axes]')}: the grid's lists make {n_grid} "
                                f"runs; a campaign holds at most {MAX_RUNS} (split it)")
        for combo in itertools.product(*lists):
            run = {**defaults, **dict(zip(names, combo, strict=True))}
            _resolve_by(parsed, run, None, source, grid=True)
            _check_run(kind_axes, run, len(runs), source)
            runs.append(run)
        return runs
    for i in range(n_runs):
        rng = np.random.default_rng([seed, i])
        run = dict(defaults)
        for k in sorted(plain):
            run[k] = _draw(plain[k], rng)
        _resolve_by(parsed, run, rng, source, grid=False)
        _check_run(kind_axes, run, i, source)
        runs.append(run)
    return runs


def load(path: str | Path, kinds: dict[str, dict[str, Axis]]) -> CampaignSpec:
    """Read and validate a campaign file."""
    path = Path(path)
    if not path.exists():
        raise CampaignError(f"{path}: no such campaign file")
    try:
        data = read_toml(path, "the campaign file")
    except TomlFileError as exc:
        raise CampaignError(str(exc)) from exc
    return parse(data, kinds, source=str(path))
