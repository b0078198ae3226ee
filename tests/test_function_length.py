"""No function of the package over ~100 lines without its reason beside it (issue 30).

A long function must carry, in the comment block right above its ``def`` (or its decorators),
a sentence saying why it is long ("… is long (~N lines) because/on purpose: …")."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("uvd", "drivers", "sim_bridge")
LIMIT = 100


def _comment_above(lines: list[str], first: int) -> str:
    """The contiguous comment lines right above line ``first`` (1-based)."""
    out, i = [], first - 2
    while i >= 0 and lines[i].lstrip().startswith("#"):
        out.append(lines[i].strip())
        i -= 1
    return " ".join(reversed(out))


def long_functions_without_reason() -> list[str]:
    bad = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            lines = text.splitlines()
            for node in ast.walk(ast.parse(text, filename=str(path))):
                if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    continue
                length = node.end_lineno - node.lineno + 1
                if length <= LIMIT:
                    continue
                first = min([node.lineno] + [d.lineno for d in node.decorator_list])
                if f"{node.name} is long" not in _comment_above(lines, first):
                    bad.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} "
                               f"({length} lines)")
    return bad


def test_every_long_function_says_why():
    assert long_functions_without_reason() == []


def test_the_check_finds_a_long_function_without_reason(tmp_path, monkeypatch):
    body = "\n".join(f"    x{i} = {i}" for i in range(LIMIT + 1))
    pkg = tmp_path / "uvd"
    pkg.mkdir()
    (pkg / "m.py").write_text(f"def f():\n{body}\n\n\n# g is long on purpose: a test\n"
                              f"def g():\n{body}\n")
    for name in PACKAGES[1:]:
        (tmp_path / name).mkdir()
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert [b.split()[1] for b in long_functions_without_reason()] == ["f"]
