"""``uvd replay RUN.mcap --lockstep|--realtime … [--config FILE] [--json OUT] [--quiet]``.

Feeds a black-box recording's raw bytes through the daemon's decoders and its one cycle on the
recorded clock (:mod:`uvd.runtime.replay.lockstep`) and compares every amplifier command with the
recorded one: bit-identical, or the first mismatch with its cycle, field and both values.
With ``--config`` (other gains, another controller) it compares tracking instead of bits.
Exit code 0 when the commands match (or, with ``--config``, when the replay ran to the end),
1 on a mismatch, 2 on a file that cannot be replayed.

``--realtime --can-interface IFACE --channel CH`` plays the recorded input onto a live bus and
pseudo-terminals for a daemon under test (:mod:`uvd.runtime.replay.realtime`); exit code 0
when its commands match the recording within the documented tolerance (or, with
``--config``, when it ran), 1 otherwise, 2 on a file that cannot be played.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from uvd.cliargs import int_in, output_file, output_folder, positive_float_upto


def register(sub) -> None:
    p = sub.add_parser("replay", help="replay a black-box recording through the one cycle",
                       description="Replay RUN.mcap in lockstep and compare the commands.")
    p.add_argument("recording", type=Path, metavar="RUN.mcap")
    how = p.add_mutually_exclusive_group(required=True)
    how.add_argument("--lockstep", action="store_true",
                     help="on the recorded clock, as fast as it goes, through this uvd's cycle")
    how.add_argument("--realtime", action="store_true",
                     help="play the recorded input onto a CAN bus and pseudo-terminals with its "
                          "original timing, for a daemon under test")
    rt = p.add_argument_group("--realtime")
    rt.add_argument("--can-interface", choices=("udp_multicast", "virtual", "socketcan"),
                    help="python-can interface of the bus the daemon under test is on")
    rt.add_argument("--channel", help="its channel (multicast group, virtual name, vcan0)")
    rt.add_argument("--can-port", type=int_in(1, 65535), help="UDP port of udp_multicast")
    rt.add_argument("--work", type=output_folder, metavar="DIR",
                    help="folder of the pseudo-terminals, the daemon's configuration and its "
                         "recording (default: a new one in the temporary directory)")
    rt.add_argument("--daemon", action="store_true",
                    help="start the daemon under test (uvd run --arm) and stop it at the end")
    rt.add_argument("--wait", type=positive_float_upto(86400.0), default=60.0, metavar="S",
                    help="longest wait for the daemon's first frame (default 60 s, at most a "
                         "day)")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="replay with this configuration instead of the recorded one "
                        "(compares tracking, not bits)")
    p.add_argument("--json", type=output_file, metavar="OUT", help="write the report to this file")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(handler=_run)


def _run(args) -> int:
    if args.realtime:
        return _run_realtime(args)
    from uvd.jsonio import write_json
    from uvd.progress import Progress
    from uvd.runtime.replay.lockstep import replay_lockstep
    from uvd.telemetry.recording import RecordingError

    t0 = time.monotonic()
    try:
        with Progress("replay", unit="cycles", quiet=args.quiet) as p:
            rep = replay_lockstep(args.recording, config=args.config, progress=p.update)
    except RecordingError as exc:
        print(f"uvd replay: {exc}", file=sys.stderr)
        return 2
    wall = time.monotonic() - t0
    d = rep.as_dict()
    d["wall_s"] = wall
    if args.json:
        write_json(args.json, d)
    files = f" ({len(rep.files)} files of the run)" if len(rep.files) > 1 else ""
    print(f"uvd replay {args.recording}{files}: {rep.cycles} cycles in {wall:.2f} s "
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
    if m and rep.other_arithmetic():
        from uvd.blas import kernel_names
        recorded = kernel_names(rep.blas["recorded"])
        here = kernel_names(rep.blas["replayed"] or {}) or "unknown"
        print(f"  the recording was made with BLAS kernels {recorded}, this replay runs "
              f"{here}: they round differently (largest thrust difference "
              f"{rep.largest_difference_n:.3g} N). Replay on the recording's machine, or here "
              f"with OPENBLAS_CORETYPE={recorded.split(', ')[0]} if this CPU has that "
              "kernel's instructions")
    return 1


def _run_realtime(args) -> int:
    from uvd.jsonio import write_json
    from uvd.progress import Progress
    from uvd.runtime.replay.realtime import default_work_dir, replay_realtime
    from uvd.telemetry.recording import RecordingError

    if not (args.can_interface and args.channel):
        print("uvd replay: --realtime needs --can-interface and --channel", file=sys.stderr)
        return 2

    def ready(cfg: Path) -> None:
        print(f"uvd replay: waiting for the daemon under test: uvd run --config {cfg} --arm",
              flush=True)

    work = args.work or default_work_dir(args.recording)
    try:
        with Progress("played", unit="frames", quiet=args.quiet) as p:
            res = replay_realtime(args.recording, work, interface=args.can_interface,
                                  channel=args.channel, can_port=args.can_port,
                                  config=args.config, start_daemon=args.daemon,
                                  wait_s=args.wait, ready=ready, progress=p.update)
    except RecordingError as exc:
        print(f"uvd replay: {exc}", file=sys.stderr)
        return 2
    d = res.as_dict()
    if args.json:
        write_json(args.json, d)
    pl, c = res.playing, res.commands
    if "error" in pl:
        print(f"uvd replay {args.recording}: {pl['error']}")
        return 1
    print(f"uvd replay {args.recording} --realtime: {pl['played']['can']} CAN frames and "
          f"{pl['played']['serial']} serial reads played ({pl['dropped']} dropped), "
          f"{pl['frames_matched']} of the daemon's frames aligned; lateness p50 "
          f"{pl['late_ms_p50']:.2f} ms, p99 {pl['late_ms_p99']:.2f} ms")
    print(f"  commands: {c['cycles_compared']} cycles compared, {c['identical']} identical, "
          f"{c['within_tolerance']} within {c['tolerance_permille']} ‰ of rated torque, "
          f"largest difference {c['max_diff_permille']} ‰, mean "
          f"{c['mean_diff_permille'] or 0.0:.1f} ‰")
    for k in ("recorded", "live"):
        t = res.tracking.get(k, {})
        if t.get("cycles"):
            print(f"  {k:>8}: position MNE {t['position_mne']:.4f}, velocity MNE "
                  f"{t['velocity_mne']:.4f} over {t['cycles']} armed cycles, thrust RMS "
                  f"{t['thrust_rms_n']:.1f} N")
    if res.stopped:
        print(f"  stopped: {res.stopped}")
    if res.operator_commands:
        print(f"  not re-issued (no wire for them yet): operator commands "
              f"{', '.join(res.operator_commands)} — commands after them differ")
    if args.config is not None:
        rec, live = res.tracking.get("recorded", {}), res.tracking.get("live", {})
        if rec.get("cycles") and live.get("cycles"):
            print(f"  another configuration: thrust RMS {live['thrust_rms_n']:.1f} N against "
                  f"{rec['thrust_rms_n']:.1f} N recorded "
                  f"({100 * (live['thrust_rms_n'] / rec['thrust_rms_n'] - 1):+.1f} %); "
                  "position MNE "
                  f"{live['position_mne']:.4f} against {rec['position_mne']:.4f} — in an open-loop "
                  "replay the motion is the recording's, so other gains show in the commands")
        return 0
    print("  MATCH: the daemon under test commands what the recording did, within tolerance"
          if c["match"] else "  NO MATCH: the commands differ beyond tolerance")
    return 0 if c["match"] else 1
