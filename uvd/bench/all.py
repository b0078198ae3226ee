"""``make bench``: run every registered benchmark, print its figures, write ``out/bench/NAME.json``
and append the figures to ``docs/BENCHMARKS.md``."""

from __future__ import annotations

import sys
from pathlib import Path

from uvd.bench import registry
from uvd.cli import main as uvd_main


def main(argv: list[str] | None = None) -> int:
    names = argv if argv else sorted(registry())
    failed = []
    for i, name in enumerate(names, 1):
        print(f"[bench {i}/{len(names)}] uvd bench {name}", flush=True)
        rc = uvd_main(["bench", name, "--json", str(Path("out/bench") / f"{name}.json"),
                       "--report", "docs/BENCHMARKS.md"])
        if rc != 0:
            failed.append(name)
    if failed:
        print(f"benchmarks that failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
