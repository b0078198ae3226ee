"""``uvd replay RUN.mcap --lockstep [--config FILE] [--json OUT] [--quiet]``.

Feeds a black-box recording's raw bytes through the daemon's decoders and its one cycle on the
recorded clock (:mod:`uvd.runtime.replay`) and compares every amplifier command with the
recorded one: bit-identical, or the first mismatch with its cycle, field and both values.
With ``--config`` (other gains, another controller) it compares tracking instead of bits.
Exit code 0 when the commands match (or, with ``--config``, when the replay ran to the end),
1 on a mismatch, 2 on a file that cannot be replayed.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("replay", help="replay a black-box recording through the one cycle",
                       description="Replay RUN.mcap in lockstep and compare the commands.")
    p.add_argument("recording", type=Path, metavar="RUN.mcap")
    p.add_argument("--lockstep", action="store_true", required=True,
                   help="on the recorded clock, as fast as it goes (the only mode so far)")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="replay with this configuration instead of the recorded one "
                        "(compares tracking, not bits)")
    p.add_argument("--json", type=Path, metavar="OUT", help="write the report to this file")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(handler=_run)


def _run(args) -> int:
    from uvd.jsonio import write_json
    from uvd.runtime.replay import replay_lockstep
    from uvd.telemetry.mcap_recorder import RecordingError

    state = {"next": time.monotonic() + 1.0}

    def progress(k: int, n: int) -> None:
        if args.quiet or time.monotonic() < state["next"]:
            return
        state["next"] = time.monotonic() + 1.0
        print(f"  replayed {k} / {n} cycles", file=sys.stderr)

    t0 = time.monotonic()
    try:
        rep = replay_lockstep(args.recording, config=args.config, progress=progress)
    except RecordingError as exc:
        print(f"uvd replay: {exc}", file=sys.stderr)
        return 2
    wall = time.monotonic() - t0
    d = rep.as_dict()
    d["wall_s"] = wall
    if args.json:
        write_json(args.json, d)
    print(f"uvd replay {args.recording}: {rep.cycles} cycles in {wall:.2f} s "
          f"({rep.operator_commands} operator commands re-applied, "
          f"{rep.missing_samples} samples not found in the raw frames)")
    if rep.stopped:
        print(f"  stopped: {rep.stopped}")
    tr = rep.tracking
    for k in ("recorded", "replayed"):
        t = tr.get(k, {})
        if t.get("cycles"):
            print(f"  {k:>8}: position MNE {t['position_mne']:.4f}, velocity MNE "
                  f"{t['velocity_mne']:.4f} over {t['cycles']} armed cycles, thrust RMS "
                  f"{t['thrust_rms_n']:.1f} N")
    if not rep.same_config:
        print("  another configuration: commands not compared bit for bit")
        return 0
    if rep.mismatches == 0 and rep.commands_compared > 0:
        print(f"  bit-identical: {rep.commands_compared} of {rep.commands_compared} commands")
        return 0
    m = rep.first_mismatch
    print(f"  MISMATCH: {rep.mismatches} of {rep.commands_compared} commands differ; first at "
          f"cycle {m['cycle']} (t = {m['t_ns']} ns), {m['field']}: recorded {m['recorded']!r}, "
          f"replayed {m['replayed']!r}" if m else "  no command compared")
    return 1
