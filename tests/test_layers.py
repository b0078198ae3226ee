"""Imports point downward only (the layer order of docs/architecture.md), and the pure packages
(uvd/model, uvd/control, uvd/estimation) do no I/O, read no clock and log nothing.

A small AST scan of every module of ``uvd``, ``drivers`` and ``sim_bridge``: each ``import``
and ``from … import`` (relative ones resolved; also those inside functions and under
``TYPE_CHECKING`` — a dependency is a dependency). Imports by computed name
(``importlib.import_module(f"…")``) are not seen.

Layers, top to bottom (a module may import its own layer and any layer below it):

  0. uvd.cli, uvd.commands, uvd.__main__
  1. uvd.lockstep, uvd.experiments, uvd.bench, uvd.fdc, uvd.campaign
  2. uvd.runtime, uvd.links (the daemon and its faces: one layer)
  3. uvd.telemetry
  4. uvd.io
  5. uvd.core
  6. uvd.control, uvd.estimation
  7. uvd.model
  8. drivers            (imports nothing of uvd but uvd.errors, uvd.geometry and uvd.spells)

``sim_bridge`` may import drivers, uvd.model, uvd.io, uvd.control and the utilities — nothing
of uvd.runtime: it takes a configuration of its own (sim_bridge.config); only the top two
layers may import sim_bridge. The utilities (uvd.errors, uvd.jsonio, uvd.blas, uvd._jitcache,
uvd.progress, uvd.netports, uvd.geometry, uvd.rtthreads, uvd.shipped, uvd.zenoh_callbacks,
uvd.zenoh_names, uvd.cliargs, uvd.spells, uvd.claims, the ``uvd`` package) are importable
from anywhere in uvd and import no other layer. drivers imports nothing of uvd but
uvd.errors, uvd.geometry and uvd.spells; uvd.fdc (uvd-fdc, a process of its own) nothing
but itself, uvd.zenoh_callbacks, uvd.zenoh_names and uvd.cliargs.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("uvd", "drivers", "sim_bridge")

LAYERS: tuple[tuple[str, ...], ...] = (
    ("uvd.cli", "uvd.commands", "uvd.__main__"),
    ("uvd.lockstep", "uvd.experiments", "uvd.bench", "uvd.fdc", "uvd.campaign"),
    ("uvd.runtime", "uvd.links"),
    ("uvd.telemetry",),
    ("uvd.io",),
    ("uvd.core",),
    ("uvd.control", "uvd.estimation"),
    ("uvd.model",),
    ("drivers",),
)
UTILITIES = ("uvd", "uvd.errors", "uvd.jsonio", "uvd.blas", "uvd._jitcache", "uvd.progress",
             "uvd.netports", "uvd.geometry", "uvd.rtthreads", "uvd.shipped", "uvd.zenoh_callbacks",
             "uvd.zenoh_names", "uvd.cliargs", "uvd.spells", "uvd.claims")
#: uvd-fdc imports nothing of uvd but itself and this: how any process of the project ends a
#: Zenoh session's callback threads (zenoh-python's, not uvd's: it imports nothing of the
#: project, checked below) — the daemon's Zenoh face needs it as much as uvd-fdc does
#: — and, as pure utilities that import nothing of the project either, the key space's and
#: endpoints' rules (the daemon's configuration checks the same) and the command line's types
FDC_MAY_IMPORT = ("uvd.zenoh_callbacks", "uvd.zenoh_names", "uvd.cliargs")
#: drivers never import uvd, except three pure modules that import nothing of the project: the
#: design card's one error hierarchy (UvdError and the matching built-ins), the attitude
#: conventions every layer shares (Euler ⇄ R, η, the one angle wrap) and when failures in
#: spells are told (the CAN log's, as the record files')
DRIVERS_MAY_IMPORT = ("uvd.errors", "uvd.geometry", "uvd.spells")
SIM_BRIDGE_MAY_IMPORT = ("sim_bridge", "drivers", "uvd.model", "uvd.io", "uvd.control")
#: the layers that may import sim_bridge (lockstep, its experiments, benchmarks, `uvd demo`)
SIM_BRIDGE_IMPORTED_BY = (0, 1)

#: What a module of uvd/model, uvd/control, uvd/estimation may import besides the project's
#: own modules (which the layer rule checks): numerics, and standard-library modules that do
#: no I/O, read no clock and log nothing. Extend only with such modules.
PURE_PACKAGES = ("uvd.model", "uvd.control", "uvd.estimation", "uvd.geometry")
PURE_MAY_IMPORT = {
    "numpy", "scipy", "numba", "cvxpy",
    "__future__", "abc", "collections", "dataclasses", "enum", "functools", "itertools",
    "math", "numbers", "operator", "typing", "warnings",
}
#: Calls that do I/O whatever the imports: builtins, and numpy's file readers and writers.
PURE_FORBIDDEN_CALLS = {"open", "print", "input", "breakpoint", "exec", "eval", "__import__"}
PURE_FORBIDDEN_ATTRS = {"load", "save", "savez", "savez_compressed", "savetxt", "loadtxt",
                        "genfromtxt", "fromfile", "tofile", "memmap", "fromregex"}


# --------------------------------------------------------------------------------- scanning
def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(module: str, source: str, *, is_package: bool) -> Iterator[tuple[str, int]]:
    """(imported module, line) for every import statement of ``source``."""
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                yield node.module, node.lineno
                continue
            base = module.split(".") if is_package else module.split(".")[:-1]
            base = base[:len(base) - node.level + 1]
            target = ".".join(base + ([node.module] if node.module else []))
            if node.module is None:  # from . import a, b: each name may be a module
                for alias in node.names:
                    yield f"{target}.{alias.name}", node.lineno
            else:
                yield target, node.lineno


def _within(name: str, prefixes) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def layer_of(module: str) -> int | str | None:
    """The layer index, "utility", "sim_bridge", or None (not a project module)."""
    if _within(module, UTILITIES[1:]) or module == "uvd":
        return "utility"
    if _within(module, ("sim_bridge",)):
        return "sim_bridge"
    for i, prefixes in enumerate(LAYERS):
        if _within(module, prefixes):
            return i
    return None


def rule_broken(importer: str, imported: str) -> str | None:
    """Why ``importer`` may not import ``imported`` (None: it may)."""
    src, dst = layer_of(importer), layer_of(imported)
    if dst is None:
        if imported.split(".")[0] in PACKAGES:
            return f"{imported} is in no layer (add it to LAYERS)"
        return None  # standard library or third party
    if src is None:
        return f"{importer} is in no layer (add it to LAYERS)"
    if src == "sim_bridge":
        return None if dst == "utility" or _within(imported, SIM_BRIDGE_MAY_IMPORT) else \
            "sim_bridge imports only drivers, uvd.model, uvd.io, uvd.control, utilities"
    if dst == "sim_bridge":
        return None if src in SIM_BRIDGE_IMPORTED_BY else \
            "only uvd.cli/commands/experiments/bench may import sim_bridge"
    if src == "utility":
        return None if dst == "utility" else "a utility imports no layer"
    if src == len(LAYERS) - 1:  # drivers
        if dst == src or _within(imported, DRIVERS_MAY_IMPORT):
            return None
        return "drivers never import uvd (but uvd.errors, uvd.geometry, uvd.spells)"
    if dst == "utility":
        return None
    return "imports point downward only" if dst < src else None


def project_modules() -> list[tuple[str, Path]]:
    out = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            out.append((module_name(path), path))
    return out


def scan_layers() -> dict[tuple[str, str], list[str]]:
    """{(importer, imported): ["file:line reason", …]} for every import that breaks a rule."""
    found: dict[tuple[str, str], list[str]] = {}
    for module, path in project_modules():
        for imported, line in imports_of(module, path.read_text(encoding="utf-8"),
                                         is_package=path.name == "__init__.py"):
            why = rule_broken(module, imported)
            if why:
                where = f"{path.relative_to(ROOT)}:{line} {why}"
                found.setdefault((module, imported), []).append(where)
    return found


def impurities(module: str, source: str) -> list[str]:
    """What in ``source`` (a module of a pure package) does I/O, reads a clock or logs."""
    out = []
    for imported, line in imports_of(module, source, is_package=False):
        top = imported.split(".")[0]
        if top in PACKAGES or top in PURE_MAY_IMPORT:
            continue
        out.append(f"line {line}: imports {imported}")
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Name) and f.id in PURE_FORBIDDEN_CALLS:
            out.append(f"line {node.lineno}: calls {f.id}()")
        elif isinstance(f, ast.Attribute) and f.attr in PURE_FORBIDDEN_ATTRS:
            out.append(f"line {node.lineno}: calls .{f.attr}() (a file reader or writer)")
    return out


# ------------------------------------------------------------------------------------ tests
def test_every_module_is_in_a_layer():
    modules = project_modules()
    assert len(modules) > 100  # the scan sees the project
    unplaced = [m for m, _ in modules if layer_of(m) is None]
    assert not unplaced, f"modules in no layer (add them to LAYERS): {unplaced}"


def test_imports_point_downward():
    found = scan_layers()
    assert not found, "imports against the layer order:\n" + "\n".join(
        f"  {a} -> {b}: {'; '.join(w)}" for (a, b), w in sorted(found.items()))


def test_pure_packages_do_no_io_clock_or_logging():
    checked, found = 0, {}
    for module, path in project_modules():
        if _within(module, PURE_PACKAGES):
            checked += 1
            bad = impurities(module, path.read_text(encoding="utf-8"))
            if bad:
                found[str(path.relative_to(ROOT))] = bad
    assert checked >= 20
    assert not found, "I/O, clock or logging in a pure package:\n" + "\n".join(
        f"  {p}: {'; '.join(b)}" for p, b in sorted(found.items()))


# ------------------------------------------------------------------- the checker catches
@pytest.mark.parametrize(("importer", "imported", "broken"), [
    ("uvd.model.lie", "uvd.control.pdc", True),
    ("uvd.control.pdc", "uvd.model.lie", False),
    ("uvd.telemetry.sink", "uvd.runtime.config", True),
    ("uvd.telemetry.report", "uvd.links.mcap", True),
    ("uvd.links.mavlink.link", "uvd.runtime.commands", False),
    ("uvd.runtime.app", "uvd.links", False),
    ("uvd.runtime.app", "uvd.lockstep", True),
    ("uvd.runtime.app", "sim_bridge.plant", True),
    ("uvd.lockstep", "sim_bridge.plant", False),
    ("sim_bridge.plant", "uvd.model.dynamics", False),
    ("sim_bridge.bridge", "uvd.core", True),
    ("sim_bridge.bridge", "uvd.runtime.daemon", True),
    ("drivers.pd0", "uvd.errors", False),
    ("drivers.pd0", "uvd.model.lie", True),
    ("drivers.frames", "uvd.geometry", False),
    ("uvd.geometry", "uvd.model.lie", True),
    ("sim_bridge.bridge", "uvd.runtime.config", True),
    ("sim_bridge.bridge", "uvd.rtthreads", False),
    ("uvd.commands.sim_bridge", "sim_bridge.bridge", False),
    ("uvd.errors", "uvd.model.lie", True),
    ("uvd.core", "uvd.jsonio", False),
    ("uvd.core", "uvd.io.params", True),
    ("uvd.io.vehicle", "uvd.model.vehicle", False),
    ("uvd.model.lie", "os", False),  # the purity test's business, not the layers'
    ("uvd.model.lie", "uvd.nonesuch", True),
])
def test_layer_rule(importer, imported, broken):
    assert (rule_broken(importer, imported) is not None) == broken


def test_relative_imports_are_resolved():
    src = "from . import lie\nfrom ..control import pdc\nfrom .params import UVParams\n"
    got = [m for m, _ in imports_of("uvd.model.dynamics", src, is_package=False)]
    assert got == ["uvd.model.lie", "uvd.control", "uvd.model.params"]


def test_impurities_are_found():
    src = ("import os\nimport numpy as np\nfrom time import monotonic\nimport logging.handlers\n"
           "def f(x):\n    print(x)\n    np.savez('a', x=x)\n    return open('f').read()\n")
    bad = impurities("uvd.model.x", src)
    assert bad == ["line 1: imports os", "line 3: imports time",
                   "line 4: imports logging.handlers", "line 6: calls print()",
                   "line 7: calls .savez() (a file reader or writer)", "line 8: calls open()"]
    assert impurities("uvd.model.x", "import math\nimport numpy as np\nnp.sin(1.0)\n") == []


def test_the_fault_detection_client_uses_only_the_wire_contract():
    """uvd-fdc is a separate process of the fleet: it imports nothing of uvd but itself and
    :data:`FDC_MAY_IMPORT`, which import nothing of the project."""
    found, seen = {}, 0
    for module, path in project_modules():
        own = _within(module, ("uvd.fdc",))
        if own or _within(module, FDC_MAY_IMPORT):
            seen += own
            bad = [name for name, _ in imports_of(module, path.read_text(encoding="utf-8"),
                                                  is_package=path.name == "__init__.py")
                   if name and _within(name, ("uvd", "drivers", "sim_bridge"))
                   and not _within(name, ("uvd.fdc", *FDC_MAY_IMPORT) if own else ())]
            if bad:
                found[module] = bad
    assert seen >= 3 and not found, (seen, found)
