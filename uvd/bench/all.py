"""``make bench``: run every registered benchmark (or those named), print its figures, write
``out/bench/NAME.json``, append them to the history ``docs/bench/history.jsonl`` and re-render
``docs/BENCHMARKS.md`` from it (:mod:`uvd.bench.page`)."""

from __future__ import annotations

import json
import sys
import traceback
from pathlib import Path

from uvd.bench import default_args, get, registry, run
from uvd.bench.page import HISTORY, PAGE, append_history, current_commit, new_record, write_page
from uvd.jsonio import write_json

OUT = Path("out/bench")


def main(argv: list[str] | None = None) -> int:
    names = argv if argv else sorted(registry())
    commit = current_commit()  # before the history file changes
    failed = []
    for i, name in enumerate(names, 1):
        print(f"[bench {i}/{len(names)}] uvd bench {name}", flush=True)
        try:
            b = get(name)
            figures = run(b, default_args(b))
        except Exception:  # one benchmark failing does not stop the others; reported below
            traceback.print_exc()
            failed.append(name)
            continue
        print(json.dumps(figures, indent=2, default=float), flush=True)
        write_json(OUT / f"{name}.json", figures)
        append_history(HISTORY, new_record(b.name, b.summary, figures, commit=commit))
    n = write_page(HISTORY, PAGE)
    print(f"{PAGE}: rendered from {n} record(s) of {HISTORY}")
    if failed:
        print(f"benchmarks that failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
