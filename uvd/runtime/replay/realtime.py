"""``uvd replay RUN.mcap --realtime``: yesterday's inputs, on the wire, for a daemon under test.

The recording's raw input — every serial chunk (``/uvd/raw/serial``) and every CAN frame the
daemon *received* (``/uvd/raw/can``, ``rx: true``: the amplifiers' TPDOs, heartbeats, EMCYs
and SDO answers, the pressure transmitter) — is played onto pseudo-terminals and a python-can
bus with its original timing. A daemon under test (another process: a new version, other
gains) opens them exactly as it opens the vehicle's. Nothing drives a plant: the drives'
answers are the recorded ones, so the daemon's commands go nowhere but into the comparison.

The clock. The recorded timeline is mapped onto the live one by the frames the daemon under
test sends: its *k*-th frame with a CAN id is matched to the recorded daemon's *k*-th frame
with that id (the frames devices answer: NMT, SDO requests, SYNC), and every match sets the offset
between the two clocks. So an SDO answer follows the live request by its recorded delay, a
drive's feedback follows the live SYNC as it followed the recorded one (a received frame is
never played before the live counterpart of the frame it followed, its *gate*), and the
instruments' bytes keep their recorded phase to the control cycles. Nothing is played before
the daemon's first frame (``wait_s`` bounds that wait); the recording's end plus ``tail_s``
ends the run.

The comparison is made on the wire too: the target torque (‰ of rated, RPDO1 bytes 2–3,
``drivers/can/amplifier.eds``) each drive was sent in the cycle between two SYNCs, recorded against
live, cycle by cycle (the *j*-th SYNC of each). Tracking (navigation against reference) comes
from the daemon under test's own recording when it writes one (``--daemon`` sets that up).

Only the MCAP channels (docs/recording.md) and the wire are used — no class of the daemon.
"""

from __future__ import annotations

import base64
import contextlib
import math
import os
import struct
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uvd.runtime.process import stop_daemon
from uvd.runtime.replay.records import (
    malformed_message,
    require_start,
    run_messages,
    serial_entry,
)
from uvd.telemetry.recording import RecordingError, read_messages

__all__ = ["WireRecording", "load_wire", "RealtimePlayer", "live_config",
           "compare_commands", "TOLERANCE_PERMILLE", "replay_realtime"]

SYNC_ID = 0x080
RPDO1_BASE = 0x200

#: a live command within this many ‰ of rated torque of the recorded one counts as matching
#: (the two runs see the same bytes, stamped some hundred µs apart, and AMBC integrates the
#: difference: docs/recording.md has the figures)
TOLERANCE_PERMILLE = 20
#: share of the compared cycles that must be within tolerance for the summary to say "match"
MATCH_SHARE = 0.95


def _aligns(cid: int) -> bool:
    """The daemon's frames the devices answer — NMT, SYNC, SDO requests — and so the ones
    the two clocks are aligned on (its heartbeat and RPDOs follow its own timers)."""
    return cid in (0x000, SYNC_ID) or 0x600 < cid < 0x680


@dataclass
class WireRecording:
    """What the realtime replay plays and compares, read from one ``.mcap`` file."""

    path: Path
    config_toml: str
    serial: list[tuple[int, str, bytes]]  # (t_ns, source, bytes), in time order
    can: list[tuple[int, Any, tuple[int, int] | None]]  # (t_ns, frame, gate), in time order
    tx: dict[int, list[int]]  # CAN id → recorded send times of the daemon's frames of that id
    # (alignment ids only, see _aligns; ``sent_ids`` are all the ids the daemon sent)
    sent_ids: frozenset[int]
    commands: list[dict[int, int]]  # per SYNC interval: node → target torque (‰)
    cycles: list[dict[str, Any]]
    operator_commands: list[str]  # names of the recorded commands besides auto-arm
    nodes: tuple[int, ...]
    #: the first damaged record or message, where what is read ends (None: none)
    damaged: str | None = None


def load_wire(path: str | Path) -> WireRecording:
    """Read the raw channels, the start record and the cycles of a recording: the run
    ``path`` is the first file of, file after file
    (:func:`~uvd.runtime.replay.records.run_messages`).

    A damaged message, or a record that is not what its schema promises in a field a replay
    reads (:func:`~uvd.runtime.replay.records.record_problem`, as the lockstep replay judges
    it), ends what is read, as a cut does (the run is played up to its last cycle before
    it); ``damaged`` names it.

    Raises
    ------
    RecordingError
        Not MCAP, or no start record, no raw CAN frames or no cycles before any damage (the
        message names the file and the problem).
    """
    import can

    path = Path(path)
    start, serial, received, cycles, others = None, [], [], [], []
    sent: list[tuple[int, int, bytes]] = []  # (t_ns, id, data) of the daemon's frames
    damage: list[str] = []
    topics = ("/uvd/start", "/uvd/raw/serial", "/uvd/raw/can", "/uvd/cycle", "/uvd/command")
    for topic, t_ns, m in run_messages(path, topics, damage, []):
        if topic == "/uvd/cycle":
            cycles.append(m)
        elif topic == "/uvd/command":
            if m.get("source") != "uvd run --arm":
                others.append(str(m.get("command")))
        elif topic == "/uvd/start":
            if start is None:
                start = m
        else:
            try:
                if topic == "/uvd/raw/serial":
                    serial.append(serial_entry(m))
                else:
                    data = base64.b64decode(m["data"], validate=True)
                    cid, t = int(m["id"]), int(m["t_ns"])
                    if m["rx"]:
                        received.append((t, can.Message(
                            arbitration_id=cid, data=data, is_extended_id=bool(m["extended"]),
                            is_remote_frame=bool(m["remote"]),
                            is_error_frame=bool(m["error"]))))
                    else:
                        sent.append((t, cid, data))
            except (KeyError, ValueError, TypeError) as exc:  # damaged: what is read ends
                damage.append(malformed_message(topic, t_ns, exc))
                break
    before = f" before {damage[0]}" if damage else ""
    require_start(path, start, before)
    if not sent:
        raise RecordingError(f"{path}: no CAN frames sent by the daemon (/uvd/raw/can)"
                             f"{before}: nothing to align a live daemon with")
    if not cycles:
        raise RecordingError(f"{path}: no cycle records (/uvd/cycle){before}")
    # the run up to its last cycle: the recorded shutdown (drives disabled, NMT) is not played
    end = int(cycles[-1]["t_ns"]) + 100_000_000
    serial = sorted(e for e in serial if e[0] <= end)
    sent.sort(key=lambda e: e[0])
    received = sorted((e for e in received if e[0] <= end), key=lambda e: e[0])
    doc = tomllib.loads(start["config_toml"])
    nodes = tuple(doc.get("can", {}).get("amplifiers", {}).get("node_ids", (1, 2, 3, 4, 5, 6)))
    commands = _commands([(cid, data) for _, cid, data in sent], nodes)
    # each received frame is gated on the daemon's frame sent last before it (its k-th of that
    # id): an SDO answer on its request, a drive's feedback on its SYNC
    tx: dict[int, list[int]] = {}
    sent_ids = frozenset(cid for _, cid, _ in sent)
    gated, i, gate = [], 0, None
    aligning = [(t, cid) for t, cid, _ in sent if _aligns(cid)]
    for t, msg in received:
        while i < len(aligning) and aligning[i][0] <= t:
            cid = aligning[i][1]
            times = tx.setdefault(cid, [])
            gate = (cid, len(times))
            times.append(aligning[i][0])
            i += 1
        if msg.arbitration_id not in sent_ids:  # a frame of the daemon's own ids would be
            gated.append((t, msg, gate))  # taken for the live daemon's echo
    for t, cid in aligning[i:]:
        tx.setdefault(cid, []).append(t)
    return WireRecording(path, start["config_toml"], serial, gated, tx, sent_ids, commands,
                         cycles, others, nodes, damage[0] if damage else None)


def _commands(frames, nodes) -> list[dict[int, int]]:
    """Target torques per SYNC interval from the frames a daemon sent, in order."""
    rpdo = {RPDO1_BASE + n: n for n in nodes}
    out: list[dict[int, int]] = [{}]
    for cid, data in frames:
        if cid == SYNC_ID:
            out.append({})
        elif cid in rpdo and len(data) >= 4:
            out[-1][rpdo[cid]] = struct.unpack_from("<h", data, 2)[0]
    return out


class RealtimePlayer:
    """Play a :class:`WireRecording` onto ``bus`` and ``ports`` on the live daemon's clock.

    Parameters
    ----------
    rec : WireRecording
    bus : can.BusABC
        Shared with the daemon under test (sends the recorded received frames, hears the
        daemon's).
    ports : dict
        Source name (``ins``, ``dvl``, ``depth``) → object with ``write(bytes) -> bool``.
    wait_s : float
        Longest wait for the daemon under test's first frame.
    tail_s : float
        Listening after the last recorded frame (the last commands).
    gate_timeout_s : float
        A received frame waits for the live counterpart of the daemon's frame it followed
        (its gate) at most this long past its time; then it is played anyway (counted). A
        daemon silent this long gates nothing (played on the clock): one that stops costs
        one timeout, not one per frame, and the replay ends with the recording.
    clock : callable
        Monotonic nanoseconds.
    progress : callable, optional
        ``progress(done, total)`` from the playing thread.
    """

    def __init__(self, rec: WireRecording, bus, ports: dict[str, Any], *, wait_s: float = 60.0,
                 tail_s: float = 0.5, gate_timeout_s: float = 0.5,
                 clock: Callable[[], int] = time.monotonic_ns,
                 progress: Callable[[int, int], None] | None = None,
                 gone: Callable[[], str | None] | None = None) -> None:
        self.rec, self.bus, self.ports = rec, bus, ports
        self.gone = gone  # why the daemon under test has ended, or None while it runs
        self.wait_s, self.tail_s, self.clock, self.progress = wait_s, tail_s, clock, progress
        self.gate_timeout_s = gate_timeout_s
        self.ungated: list[tuple[int, int, int, int]] = []  # (t, id, gate id, gate k)
        self.offset_ns: int | None = None
        self._live_ns = 0  # when the daemon last sent an aligning frame
        self.matched = 0
        self.unmatched = 0
        self._counts: dict[int, int] = {}
        self._live_frames: list[tuple[int, bytes]] = []
        self.played = {"can": 0, "serial": 0}
        self.dropped = {"can": 0, "serial": 0}
        self.late_ms: list[float] = []
        self._stop = threading.Event()

    # -- the live side (receiving thread) --

    def _listen(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(0.05)
            except Exception:  # noqa: BLE001 - a bus that fails ends the listening
                return
            if msg is not None:
                self.on_live(msg.arbitration_id, bytes(msg.data), self.clock())

    def on_live(self, cid: int, data: bytes, t_ns: int) -> None:
        """One frame heard on the bus: the daemon under test's (matched) or not."""
        if cid not in self.rec.sent_ids:
            return  # ours (the udp echo) or a stranger's
        self._live_frames.append((cid, data))
        times = self.rec.tx.get(cid)
        if times is None:
            return
        k = self._counts.get(cid, 0)
        self._counts[cid] = k + 1
        if k < len(times):
            self.offset_ns = t_ns - times[k]
            self._live_ns = t_ns
            self.matched += 1
        else:
            self.unmatched += 1

    # -- playing --

    def run(self) -> dict[str, Any]:
        """Play everything; returns the playing figures (the comparison is separate)."""
        listener = threading.Thread(target=self._listen, name="replay-listen", daemon=True)
        listener.start()
        try:
            deadline = self.clock() + int(self.wait_s * 1e9)
            while self.offset_ns is None:
                if self.gone is not None and (why := self.gone()):
                    return {"error": why}
                if self.clock() > deadline:
                    return {"error": f"no daemon appeared on the bus within {self.wait_s:g} s"}
                time.sleep(0.005)
            ser, fr = self.rec.serial, self.rec.can
            i = j = 0
            total = len(ser) + len(fr)
            gate_ns = int(self.gate_timeout_s * 1e9)
            while i < len(ser) or j < len(fr):
                now, off, wait = self.clock(), self.offset_ns, 5_000_000
                if i < len(ser):
                    due = ser[i][0] + off
                    if now >= due:
                        self._emit_serial(ser[i][1], ser[i][2], now - due)
                        i += 1
                        continue
                    wait = min(wait, due - now)
                if j < len(fr):
                    t, msg, gate = fr[j]
                    due = t + off
                    # gated until the live daemon has sent the frame it follows; a daemon
                    # silent for gate_timeout_s (stopped, hung) gates nothing: never a hang
                    if now >= due and (gate is None or self._counts.get(gate[0], 0) > gate[1]
                                       or now - due > gate_ns
                                       or now - self._live_ns > gate_ns):
                        if gate is not None and self._counts.get(gate[0], 0) <= gate[1]:
                            self.ungated.append((t, msg.arbitration_id, *gate))
                        self._emit_can(msg, now - due)
                        j += 1
                        continue
                    wait = min(wait, max(due - now, 200_000))
                if self.progress is not None and (i + j) % 500 == 0:
                    self.progress(i + j, total)
                time.sleep(wait * 1e-9)
            time.sleep(self.tail_s)
        finally:
            self._stop.set()
            listener.join(2.0)
        late = np.asarray(self.late_ms) if self.late_ms else np.zeros(1)
        return {"played": dict(self.played), "dropped": dict(self.dropped),
                "frames_matched": self.matched, "frames_unmatched": self.unmatched,
                "frames_ungated": len(self.ungated),
                "first_ungated": [{"t_ns": t, "id": cid, "gate_id": g, "gate_k": k}
                                  for t, cid, g, k in self.ungated[:5]],
                "late_ms_p50": float(np.percentile(late, 50)),
                "late_ms_p99": float(np.percentile(late, 99)), "late_ms_max": float(late.max())}

    def _emit_serial(self, source: str, data: bytes, late_ns: int) -> None:
        port = self.ports.get(source)
        ok = port is not None and port.write(data)
        self.played["serial"] += ok
        self.dropped["serial"] += not ok
        self.late_ms.append(late_ns * 1e-6)

    def _emit_can(self, msg, late_ns: int) -> None:
        try:
            self.bus.send(msg, timeout=0.0)
            ok = True
        except Exception:  # noqa: BLE001 - python-can's CanError and OSError alike
            ok = False
        self.played["can"] += ok
        self.dropped["can"] += not ok
        self.late_ms.append(late_ns * 1e-6)

    def live_commands(self) -> list[dict[int, int]]:
        return _commands(self._live_frames, self.rec.nodes)


def compare_commands(recorded: list[dict[int, int]], live: list[dict[int, int]],
                     cycles: int | None = None,
                     tol_permille: int = TOLERANCE_PERMILLE) -> dict[str, Any]:
    """Cycle by cycle, the target torques of every drive: cycle *j* sends its RPDOs, then the
    *j*-th SYNC, so entry *j* of :func:`_commands` is cycle *j*'s.

    Up to ``cycles`` (the recorded cycles: the shutdown's zero commands are not cycles) or the
    shorter side. ``match`` is True when at least :data:`MATCH_SHARE` of the compared cycles
    are within ``tol_permille`` on every drive.
    """
    n = min(len(recorded), len(live), cycles if cycles is not None else len(recorded))
    diffs, identical, within, first = [], 0, 0, None
    for j in range(n):
        a, b = recorded[j], live[j]
        if set(a) != set(b):
            d = math.inf
        else:
            d = max((abs(a[k] - b[k]) for k in a), default=0)
        diffs.append(d)
        identical += d == 0
        within += d <= tol_permille
        if d > 0 and first is None:
            first = {"cycle": j, "recorded": a, "live": b}
    finite = [d for d in diffs if math.isfinite(d)]
    return {"cycles_compared": n, "identical": identical, "within_tolerance": within,
            "tolerance_permille": tol_permille,
            "max_diff_permille": max(diffs) if diffs else None,
            "mean_diff_permille": float(np.mean(finite)) if finite else None,
            "first_difference": first,
            "match": n > 0 and within >= MATCH_SHARE * n}


def live_config(rec_toml: str, work: Path, *, interface: str, channel: str, can_port: int | None,
                base: Path | None = None) -> Path:
    """The configuration of the daemon under test: ``base`` (or the recorded one) with its
    instruments on the replay's pseudo-terminals in ``work``, its bus on ``interface`` /
    ``channel``, its own recording in ``work/live`` and no other outputs (Zenoh, JSON lines,
    CAN log). Without Zenoh, uvd-fdc's source (``[faults.fdc]``) is off too: it needs Zenoh
    (the daemon refused to start: the black box of ``uvd demo --fault`` did not replay,
    session 34), and the replay re-issues no operator command, a fault sample among them.
    Returns the written path."""
    from uvd.io.toml import dump_toml, read_toml

    data = read_toml(base) if base else tomllib.loads(rec_toml)
    vehicle = data.get("vehicle", {}).get("name", "")
    if vehicle.endswith(".toml") and not Path(vehicle).is_absolute() and base is not None:
        data["vehicle"]["name"] = str((base.parent / vehicle).resolve())
    sensors = data.setdefault("sensors", {})
    for name in ("ins", "dvl", "depth"):
        sensors.setdefault(name, {})["port"] = str(work / name)
    leak = sensors.get("leak", {})
    if leak.get("enabled"):
        leak["path"] = str(work / "leak")
        (work / "leak").write_text(f"{1 - int(leak.get('active_level', 1))}\n")
    can_t = data.setdefault("can", {})
    can_t.pop("log", None)
    can_t.update(interface=interface, channel=channel)
    if can_port is not None:
        can_t["port"] = can_port
    data["telemetry"] = {**data.get("telemetry", {}), "jsonl": {"enabled": False},
                         "zenoh": {"enabled": False}}
    fdc = data.get("faults", {}).get("fdc")
    if isinstance(fdc, dict):
        fdc["enabled"] = False
    data["recording"] = {"enabled": True, "dir": str(work / "live")}
    out = work / "uvd-under-test.toml"
    out.write_text("# generated by uvd replay --realtime\n" + dump_toml(data), encoding="utf-8")
    return out


@dataclass
class RealtimeResult:
    """The summary of a realtime replay (``as_dict`` for ``--json``)."""

    recording: str
    config: str
    playing: dict[str, Any] = field(default_factory=dict)
    commands: dict[str, Any] = field(default_factory=dict)
    tracking: dict[str, Any] = field(default_factory=dict)
    operator_commands: list[str] = field(default_factory=list)
    daemon_exit: int | None = None
    #: where the recording's damage ended what was played (None: it was played whole)
    stopped: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def replay_realtime(path: str | Path, work: str | Path, *, interface: str, channel: str,
                    can_port: int | None = None, config: Path | None = None,
                    start_daemon: bool = False, wait_s: float = 60.0,
                    ready: Callable[[Path], None] | None = None,
                    progress: Callable[[int, int], None] | None = None) -> RealtimeResult:
    """Play ``path`` for a daemon under test; with ``start_daemon`` run it (``uvd run --arm``
    on :func:`live_config`) as a child process, else call ``ready(config path)`` and wait for
    one to appear on the bus. Returns the summary.

    Raises
    ------
    RecordingError
        The file cannot be played (names the file and the problem).
    """
    from drivers.can.bus import open_bus
    from drivers.can.config import CanBusConfig
    from drivers.pty import PtyPort
    from uvd.runtime.replay.lockstep import tracking

    rec = load_wire(path)
    work = Path(work).absolute()  # the daemon's configuration names its ports in it
    work.mkdir(parents=True, exist_ok=True)
    cfg_path = live_config(rec.config_toml, work, interface=interface, channel=channel,
                           can_port=can_port, base=config)
    bus_cfg = {"interface": interface, "channel": channel}
    if can_port is not None:
        bus_cfg["port"] = can_port
    bus = open_bus(CanBusConfig(**bus_cfg))
    ports = {name: PtyPort(work / name) for name in ("ins", "dvl", "depth")}
    result = RealtimeResult(str(rec.path), str(cfg_path),
                            operator_commands=rec.operator_commands,
                            stopped=None if rec.damaged is None else
                            f"{rec.damaged}: the run is played up to the {len(rec.cycles)} "
                            "cycles recorded before it")
    before = set((work / "live").glob("*.mcap"))  # a reused folder: earlier runs' files
    proc = log = None
    try:
        for p in ports.values():
            p.open()
        if start_daemon:
            log = (work / "daemon.log").open("wb")  # noqa: SIM115 - closed below
            proc = subprocess.Popen(  # noqa: S603 - our own interpreter and module
                [sys.executable, "-m", "uvd", "run", "--config", str(cfg_path), "--arm",
                 "--stop-with-parent", str(os.getpid())],
                stdout=subprocess.DEVNULL, stderr=log)
        elif ready is not None:
            ready(cfg_path)
        player = RealtimePlayer(rec, bus, ports, wait_s=wait_s, progress=progress,
                                gone=None if proc is None else
                                (lambda: _ended(proc, work / "daemon.log")))
        result.playing = player.run()
        result.commands = compare_commands(rec.commands, player.live_commands(),
                                           len(rec.cycles))
    finally:
        if proc is not None:
            result.daemon_exit = stop_daemon(proc, 15.0)
        if log is not None:
            log.close()
        for p in ports.values():
            p.close()
        with contextlib.suppress(Exception):
            bus.shutdown()
    live = sorted(set((work / "live").glob("*.mcap")) - before)
    result.tracking = {"recorded": tracking(rec.cycles, [c["thrust"] for c in rec.cycles])}
    if live:
        cyc = [m for _, _, m in read_messages(live[0], ["/uvd/cycle"])][:len(rec.cycles)]
        result.tracking["live"] = tracking(cyc, [c["thrust"] for c in cyc])
    return result


def _ended(proc: subprocess.Popen, log: Path) -> str | None:
    """Why the daemon started under test has ended (its exit code and its log's last lines),
    or None while it runs: said at once, where the wait for its first frame ran out after
    ``--wait`` seconds with "no daemon appeared" (session 32: a configuration it refused)."""
    if proc.poll() is None:
        return None
    try:
        lines = [x for x in log.read_text(errors="replace").splitlines() if x.strip()][-3:]
    except OSError:
        lines = []
    return (f"the daemon under test exited with code {proc.returncode} before its first frame "
            f"({log}):" + "".join(f"\n  {x}" for x in lines))


def default_work_dir(recording: Path) -> Path:
    """``<recording stem>-realtime-<pid>`` beside the temporary directory."""
    import tempfile
    return Path(tempfile.gettempdir()) / f"{recording.stem}-realtime-{os.getpid()}"
