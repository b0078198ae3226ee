"""``uvd bench loop`` runs both loops and writes the documented keys (figures are not judged
here: timing belongs to the benchmark)."""

from __future__ import annotations

import json

from uvd.cli import main


def test_bench_loop_keys(tmp_path, capsys):
    out = tmp_path / "loop.json"
    assert main(["bench", "loop", "--rate", "200", "--duration", "0.3", "--warmup", "0",
                 "--cycle", "pdc", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "ours" in text and "naive" in text
    r = json.loads(out.read_text())
    for k in ("p50", "p99", "p999", "max"):
        assert isinstance(r["lateness_us"][k], float)
    for k in ("p50", "p99"):
        assert isinstance(r["compute_us"][k], float)
        assert isinstance(r["naive_asyncio"]["lateness_us"][k], float)
    assert r["cycle"] == "pdc" and r["cycle_errors"] == 0 and isinstance(r["overruns"], int)
    assert r["cycles"] + r["skipped"] >= 50 and r["naive_asyncio"]["cycles"] > 10
    assert r["compute_us"]["p50"] > 1.0       # the PDC cycle really ran
    # the same cycle back to back, for telling code cost from cold caches
    assert r["compute_back_to_back_us"]["n"] == 2000
    assert r["compute_back_to_back_us"]["p50"] > 1.0
    # the host's steal over the measured run, on every CPU here (not pinned)
    hs = r["host_steal"]
    assert hs["cpus"] == "all"
    if hs["seconds"] is not None:
        assert hs["seconds"] >= 0.0 and 0.0 <= hs["share"] <= 1.0
