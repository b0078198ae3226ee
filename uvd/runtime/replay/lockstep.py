"""Lockstep replay of a black-box recording: the recorded raw bytes through the same decoders,
the same cycle (:func:`uvd.runtime.cycle.update`, built by :func:`uvd.runtime.build.make_cycle`
as the daemon builds it), the recorded clock — and every amplifier command compared with the
one the daemon sent.

What a recording holds for this (docs/recording.md): the start record (the configuration's
text and the online estimators' θ̂(0)), every chunk of bytes each serial instrument delivered
with its receive stamp, and per cycle its time and measured period, the receive stamps of the
samples it took, the rest of its inputs (amplifier status, overrun streak, leak, plug-in
signals) and the thrust it commanded; the commands applied at each cycle; the lifecycle's
transitions. Replay decodes the bytes with :func:`uvd.runtime.sensors.decoders` (the readers'
own codecs and converters), rebuilds each cycle's :class:`~uvd.runtime.cycle.CycleInputs`,
applies the same commands at the same cycles and runs the update on the recorded
``t_ns`` and ``dt``. The cycle is deterministic, so the commands come out bit-identical — or
the first mismatch says where they part.

With another configuration (``config``: other gains, another controller) the commands are not
expected to match; the report then compares tracking (position and velocity error against the
reference) between the recording and the replay.

A run recorded in several files (``rotate_mb`` / ``rotate_s``) is read whole from its first
(:func:`~uvd.telemetry.recording.run_files`). Not replayable (said in the report, never
silently wrong): a reload that applied keys (the replay stops there), a later file of a run
without its first (the cycle's state at its start is unknown: refused, naming the first), a
depth sensor on CAN (its samples are not raw serial bytes).
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drivers.framing import Stamped, StreamDecoder
from uvd.errors import ConfigError
from uvd.runtime.build import make_cycle
from uvd.runtime.commands import SetParams, command_from_record
from uvd.runtime.config import Config, load_config
from uvd.runtime.cycle import inputs_from_record
from uvd.runtime.replay.records import (
    malformed_message,
    require_start,
    run_messages,
    serial_entry,
)
from uvd.runtime.schema import with_values
from uvd.runtime.sensors import decoders
from uvd.runtime.supervisor import Supervisor
from uvd.telemetry.recording import RecordingError
from uvd.telemetry.records import tracking_error_norms

__all__ = ["Recording", "load_recording", "replay_lockstep", "ReplayReport", "tracking"]


@dataclass
class Recording:
    """What a replay reads from one recording file (:func:`load_recording`)."""

    path: Path
    start: dict[str, Any]
    cycles: list[dict[str, Any]]
    commands: list[dict[str, Any]]
    lifecycle: list[dict[str, Any]]
    reloads: list[dict[str, Any]]
    serial: list[tuple[str, int, bytes]]  # (source, receive t_ns, bytes), in arrival order
    #: the first damaged record or message, where what is read ends (None: none)
    damaged: str | None = None
    #: the run's files read, in order (:func:`~uvd.telemetry.recording.run_files`)
    files: list[Path] = field(default_factory=list)


def load_recording(path: str | Path) -> Recording:
    """Read the channels a replay needs from a run's ``.mcap`` files: ``path``, its first,
    and those the recorder started after it (:func:`~uvd.telemetry.recording.run_files`;
    before session 33 a replay read the first file alone, and said nothing of the rest).

    A damaged record, a message that is not JSON or a record that is not what its schema
    promises in a field the replay reads (:func:`~uvd.runtime.replay.records.record_problem`)
    ends what is read, as a cut does: every cycle before it has its inputs in the bytes
    before its own record; ``damaged`` names it — as it names a file of the run missing from
    the folder.

    Raises
    ------
    RecordingError
        Not MCAP, not a run's first file, or without a start record or cycles before any
        damage (the message names the file and what is missing).
    """
    path = Path(path)
    start = None
    cycles, commands, lifecycle, reloads, serial = [], [], [], [], []
    damage: list[str] = []
    read: list[Path] = []
    topics = ("/uvd/start", "/uvd/cycle", "/uvd/command", "/uvd/lifecycle", "/uvd/reload",
              "/uvd/raw/serial")
    for topic, t_ns, msg in run_messages(path, topics, damage, read):
        if topic == "/uvd/cycle":
            cycles.append(msg)
        elif topic == "/uvd/raw/serial":
            try:
                t_rx, source, data = serial_entry(msg)
            except (KeyError, ValueError, TypeError) as exc:  # damaged: what is read ends
                damage.append(malformed_message(topic, t_ns, exc))
                break
            serial.append((source, t_rx, data))
        elif topic == "/uvd/command":
            commands.append(msg)
        elif topic == "/uvd/lifecycle":
            lifecycle.append(msg)
        elif topic == "/uvd/reload":
            reloads.append(msg)
        elif start is None:
            start = msg
    before = f" before {damage[0]}" if damage else ""
    require_start(path, start, before)
    if not cycles:
        raise RecordingError(f"{path}: no cycle records (/uvd/cycle){before}")
    return Recording(path, start, cycles, commands, lifecycle, reloads, serial,
                     damage[0] if damage else None, read)


@dataclass
class ReplayReport:
    """The outcome of :func:`replay_lockstep` (``as_dict`` for ``--json``)."""

    recording: str
    #: the run's files read (its first, then those the recorder started after it)
    files: list[str] = field(default_factory=list)
    cycles: int = 0
    commands_compared: int = 0
    mismatches: int = 0
    first_mismatch: dict[str, Any] | None = None
    stopped: str | None = None
    missing_samples: int = 0
    operator_commands: int = 0
    same_config: bool = True
    tracking: dict[str, Any] = field(default_factory=dict)
    #: the largest |recorded − replayed| of a compared thrust (N): last bits, or a real change
    largest_difference_n: float = 0.0
    #: the BLAS kernels the recording was made with and those of this replay (uvd.blas.kernels)
    blas: dict[str, Any] = field(default_factory=dict)

    def other_arithmetic(self) -> bool:
        """The recording names BLAS kernels and this replay's are others: the arithmetic may
        round differently, so commands may differ in their last bits with nothing else
        changed."""
        recorded, replayed = self.blas.get("recorded"), self.blas.get("replayed")
        return (isinstance(recorded, dict) and bool(recorded) and recorded != replayed
                and all(isinstance(v, str) for v in recorded.values()))

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def _config_of(rec: Recording, override: str | Path | None) -> tuple[Config, bool]:
    if override is not None:
        return load_config(override), False
    # the recorded text, resolved where the daemon resolved it (its vehicle file, if any,
    # relative to the original file's folder)
    original = Path(rec.start.get("config_path") or "")
    folder = original.parent if original.parent.is_dir() else None
    with tempfile.NamedTemporaryFile("w", suffix=".toml", dir=folder, delete=False,
                                     encoding="utf-8") as fh:
        fh.write(rec.start["config_toml"])
        tmp = Path(fh.name)
    try:
        cfg = load_config(tmp)
    except ConfigError as exc:  # named by the recording, not by the temporary file
        raise ConfigError(str(exc).replace(str(tmp), f"{rec.path}'s recorded configuration")
                          ) from exc
    finally:
        tmp.unlink(missing_ok=True)
    kept = rec.start.get("params_kept") or {}
    if kept:  # parameters a ground station had set, applied at start on top of the file
        cfg, errors = with_values(cfg, kept)
        if errors:
            raise ConfigError(f"{rec.path}: the recorded params_kept do not apply: "
                              + "; ".join(f"{k}: {r}" for k, r in errors))
    return cfg, True


def _samples(cfg: Config, rec: Recording) -> dict[tuple[str, int], Any]:
    """Every sample the recorded bytes decode to, by (source, its stamp) — the stamp a cycle
    record names; of several with one stamp (frames completed by one read) the last, as the
    daemon's mailbox kept it."""
    decs = decoders(cfg)
    streams = {name: (StreamDecoder(codec, keep_raw=True), convert)
               for name, (codec, convert) in decs.items()}
    out: dict[tuple[str, int], Any] = {}
    for source, t_ns, data in rec.serial:
        dec = streams.get(source)
        if dec is None:
            continue
        decoder, convert = dec
        for msg, raw in decoder.feed(data):
            try:
                sample = convert(Stamped(t_ns, msg, raw))
            except Exception:  # noqa: BLE001 - the daemon dropped it too (counted there)
                continue
            if sample is not None:
                out[(source, int(sample.t_ns))] = sample
    return out


def tracking(cycles: list[Mapping[str, Any]], thrusts) -> dict[str, Any]:
    """Position and velocity MNE (navigation vs reference) over the armed cycles."""
    norms = [tracking_error_norms(r) for r in cycles
             if r.get("state") in ("ARMED", "FAILSAFE") and r.get("p_ref") is not None]
    dpsi, dv = [a for a, _ in norms], [b for _, b in norms]
    if not dpsi:
        return {"cycles": 0}
    return {"cycles": len(dpsi), "position_mne": float(np.mean(dpsi)),
            "velocity_mne": float(np.mean(dv)),
            "thrust_rms_n": float(np.sqrt(np.mean(np.square(thrusts)))) if len(thrusts) else 0.0}


def replay_lockstep(path: str | Path, *, config: str | Path | None = None,
                    progress: Callable[[int, int], None] | None = None) -> ReplayReport:
    """Replay a recording in lockstep (module docstring); returns the report.

    Raises
    ------
    RecordingError
        The file cannot be read as a uvd recording.
    ConfigError
        Its configuration (or ``config``) does not validate here.
    """
    rec = load_recording(path)
    try:
        return _replay(rec, config, progress)
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
        if isinstance(exc, (RecordingError, ConfigError)):
            raise
        raise RecordingError(f"{rec.path}: a record does not hold what uvd.cycle.v1 / "
                             f"uvd.start.v1 promise: {type(exc).__name__}: {exc}") from exc


def _replay(rec: Recording, config, progress) -> ReplayReport:
    if not rec.serial:
        raise RecordingError(f"{rec.path}: no raw instrument channels, the bytes a daemon read "
                             "(a lockstep experiment's recording, `uvd experiment --record`, "
                             "has none): `uvd replay --lockstep` needs a daemon's recording "
                             "(`uvd run`, `uvd demo --record`); `uvd report` draws either")
    cfg, same = _config_of(rec, config)
    if cfg.sensors.depth.source == "can":
        raise ConfigError(f"{rec.path}: the depth sensor is on CAN — its samples are not in the "
                          "raw serial channels, so this recording cannot be replayed")
    report = ReplayReport(recording=str(rec.path), files=[str(f) for f in rec.files],
                          same_config=same)
    vehicle = cfg.load_vehicle()
    sup = Supervisor(make_cycle(cfg, vehicle, estimators=_estimators(cfg, rec)))
    samples = _samples(cfg, rec)
    boot = next((tr for tr in rec.lifecycle if tr.get("to") == "STANDBY"), None)
    booted = False
    cmds = sorted(rec.commands, key=lambda c: int(c["t_ns"]))
    ci = 0
    stop_at = min((int(r["t_ns"]) for r in rec.reloads if r.get("applied")), default=None)
    set_at = min((int(c["t_ns"]) for c in cmds if c.get("command") == "SetParams"
                  and c.get("ok")), default=None)
    replayed, recorded_thrust = [], []
    n = len(rec.cycles)
    for k, r in enumerate(rec.cycles):
        t = int(r["t_ns"])
        if stop_at is not None and t > stop_at:
            report.stopped = (f"a reload applied {', '.join(_applied(rec, stop_at))} at "
                              f"t = {stop_at} ns: the replay covers the cycles before it")
            break
        if set_at is not None and t >= set_at:
            report.stopped = (f"parameters were set (SetParams) at t = {set_at} ns: the replay "
                              "covers the cycles before it")
            break
        if r.get("inputs") is None:
            report.stopped = f"cycle {k} (t = {t} ns) carries no inputs: recorded by an older uvd"
            break
        if not booted and boot is not None and int(boot["t_ns"]) <= t:
            sup.boot_complete(int(boot["t_ns"]), boot.get("cause", "drivers up"))
            booted = True
        while ci < len(cmds) and int(cmds[ci]["t_ns"]) <= t:
            c = command_from_record(cmds[ci])
            if not isinstance(c, SetParams):
                sup.apply(c, int(cmds[ci]["t_ns"]))
            report.operator_commands += 1
            ci += 1
        got = {}
        for src in ("ins", "dvl", "depth"):
            stamp = r.get(f"{src}_rx_ns")
            if stamp is not None:
                s = samples.get((src, int(stamp)))
                if s is None:
                    report.missing_samples += 1
                got[src] = s
        try:
            inp = inputs_from_record(t, r["inputs"], got.get("ins"), got.get("dvl"),
                                     got.get("depth"))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            report.stopped = (f"cycle {k} (t = {t} ns): its inputs are malformed "
                              f"({type(exc).__name__}: {exc}): the replay covers the "
                              f"{report.cycles} cycles recorded before it")
            break
        res = sup.update(inp, float(r["dt"]))
        thrust = res.out.thrust_n
        want = np.asarray(r["thrust"], dtype=float)
        report.cycles += 1
        replayed.append(_as_record(res, r))
        recorded_thrust.append(want)
        if same:
            report.commands_compared += 1
            bad = None
            if want.shape != thrust.shape or not np.array_equal(want, thrust):
                bad = _mismatch(k, t, want, thrust, r, res)
                if want.shape == thrust.shape:
                    report.largest_difference_n = max(report.largest_difference_n,
                                                      float(np.max(np.abs(want - thrust))))
            elif "thruster_eta" in r["inputs"]:
                bad = _eta_mismatch(k, t, r["inputs"]["thruster_eta"], res.thruster_eta)
            if bad is not None:
                report.mismatches += 1
                if report.first_mismatch is None:
                    report.first_mismatch = bad
        if progress is not None:
            progress(k + 1, n)
    if report.stopped is None and rec.damaged is not None:
        report.stopped = (f"{rec.damaged}: the replay covers the {report.cycles} cycles "
                          "recorded before it")
    from uvd.blas import kernels
    report.blas = {"recorded": rec.start.get("blas"), "replayed": kernels()}
    report.tracking = {"recorded": tracking(rec.cycles[:report.cycles], recorded_thrust),
                       "replayed": tracking(replayed, [x["thrust"] for x in replayed])}
    return report


def _estimators(cfg: Config, rec: Recording):
    """The online estimators as the recorded run started them (its θ̂(0), not the file's)."""
    if not cfg.estimation.aid:
        return ()
    from uvd.estimation.aid import aid6_estimator
    theta0 = (rec.start.get("estimators") or {}).get("aid6")
    return (aid6_estimator(None if theta0 is None else np.asarray(theta0, dtype=float),
                           cfg.estimation.aid_params()),)


def _applied(rec: Recording, t_ns: int) -> list[str]:
    return next((list(r.get("applied") or ()) for r in rec.reloads if int(r["t_ns"]) == t_ns),
                [])


def _as_record(res, r: Mapping[str, Any]) -> dict[str, Any]:
    out = res.out
    ref = out.reference
    return {"t_ns": r["t_ns"], "state": res.state.value, "p": out.nav.H[:3, 3],
            "R": out.nav.H[:3, :3], "v": out.nav.v, "thrust": out.thrust_n,
            "p_ref": None if ref is None else ref.H[:3, 3],
            "R_ref": None if ref is None else ref.H[:3, :3],
            "v_ref": None if ref is None else ref.v}


def _eta_mismatch(k: int, t: int, want, got) -> dict[str, Any] | None:
    """The recorded effectiveness η against the replayed one (None: the same, bit for bit;
    None on both sides: every thruster healthy)."""
    if want is None and got is None:
        return None
    w = None if want is None else np.asarray(want, dtype=float)
    if w is not None and got is not None and w.shape == got.shape and np.array_equal(w, got):
        return None
    return {"cycle": k, "t_ns": t, "field": "thruster_eta",
            "recorded": None if w is None else w.tolist(),
            "replayed": None if got is None else np.asarray(got).tolist()}


def _mismatch(k: int, t: int, want, got, r, res) -> dict[str, Any]:
    if want.shape != got.shape:
        return {"cycle": k, "t_ns": t, "field": "thrust", "recorded": want.tolist(),
                "replayed": got.tolist(), "what": "different number of thrusters"}
    i = int(np.flatnonzero(want != got)[0])
    return {"cycle": k, "t_ns": t, "field": f"thrust[{i}]", "recorded": float(want[i]),
            "replayed": float(got[i]),
            "relative": float(abs(want[i] - got[i]) / max(abs(want[i]), 1e-300))
            if math.isfinite(want[i]) else None,
            "recorded_mode": r.get("mode"), "replayed_mode": str(res.out.mode),
            "recorded_action": r.get("action"), "replayed_action": res.decision.action.label}
