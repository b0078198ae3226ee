"""Emulated CANopen nodes: the NMT/heartbeat/EMCY skeleton and the CiA 402 amplifier.

Each node is a ``canopen.LocalNode`` (its object dictionary, SDO server and PDO maps come
from the same EDS the driver reads) plus the behaviour of a device: NMT states, heartbeat
production and consumption, EMCY, and for the amplifier the CiA 402 power state machine,
synchronous RPDO application, the RPDO deadline (command timeout) and fault injection.

All methods are called under the owning :class:`~sim_bridge.amplifiers.emulators.CanEmulators`
lock, from the bus's receive thread (frames) or its tick thread (time).
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

import canopen
from canopen.sdo import SdoAbortedError

from drivers.can import cia402
from drivers.can.amplifier import load_od
from drivers.can.bus import FrameDropped

log = logging.getLogger(__name__)

NMT_BOOT = 0
NMT_STOPPED = 4
NMT_OPERATIONAL = 5
NMT_PRE_OPERATIONAL = 127
_NMT_CMD = {0x01: NMT_OPERATIONAL, 0x02: NMT_STOPPED, 0x80: NMT_PRE_OPERATIONAL}
NMT_NAMES = {0: "boot_up", 4: "stopped", 5: "operational", 127: "pre_operational"}


class EmulatedNode:
    """NMT slave with heartbeat producer/consumer and EMCY producer on a LocalNode.

    Parameters
    ----------
    network : canopen.Network
        The emulators' network (a :class:`drivers.can.bus.UvdNetwork`).
    node_id : int
    eds : Path
        Object dictionary.
    lock : threading.RLock, optional
        The owner's lock, taken by the frame handlers this node registers itself.
    clock : callable, optional
        Monotonic nanoseconds.
    """

    def __init__(self, network: canopen.Network, node_id: int, eds: Path, *,
                 lock: threading.RLock | None = None,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.node_id = node_id
        self.network = network
        self.lock = lock or threading.RLock()
        self.clock = clock
        self.local = canopen.LocalNode(node_id, load_od(eds, node_id, f"emulated node {node_id}"))
        network.add_node(self.local)
        # route SDO and NMT through this object so that a silent node hears nothing
        network.unsubscribe(self.local.sdo.rx_cobid, self.local.sdo.on_request)
        network.unsubscribe(0, self.local.nmt.on_command)
        network.subscribe(self.local.sdo.rx_cobid, self._on_sdo)
        self.local.add_write_callback(self._on_write)
        self.local.add_read_callback(self._on_read)
        self.silent = False
        self.silent_until_ns = 0
        self.nmt_state = NMT_BOOT
        self.hb_period_ms = self._od_int(0x1017, 0)
        self._last_hb_ns = 0
        self.consumer: tuple[int, int] | None = None  # (producer id, time ms)
        self.consumer_seen_ns = 0
        self.error_register = 0
        self.counters = {"emcy_tx": 0, "heartbeats_tx": 0, "sdo_rx": 0, "nmt_rx": 0,
                         "dropped_tx": 0}

    # -- helpers --
    def _od_int(self, index: int, sub: int) -> int:
        try:
            obj = self.local.object_dictionary[index]
            if sub or not isinstance(obj, canopen.objectdictionary.ODVariable):
                obj = obj[sub]
            return int(obj.decode_raw(self.local.get_data(index, sub)))
        except (KeyError, SdoAbortedError, struct.error, TypeError, ValueError):
            return 0

    def send(self, cob_id: int, data: bytes) -> bool:
        try:
            self.network.send_message(cob_id, data)
            return True
        except FrameDropped:
            self.counters["dropped_tx"] += 1
            return False

    def emcy(self, code: int, data: bytes = b"") -> None:
        """Send EMCY ``code`` with the matching error register (code 0 = error reset)."""
        self.error_register = cia402.error_register_for(code)
        payload = struct.pack("<HB5s", code, self.error_register, data[:5])
        if self.send(0x80 + self.node_id, payload):
            self.counters["emcy_tx"] += 1

    def heartbeat(self, now: int) -> None:
        self._last_hb_ns = now
        if self.send(0x700 + self.node_id, bytes([self.nmt_state])):
            self.counters["heartbeats_tx"] += 1

    # -- NMT --
    def boot(self, now: int) -> None:
        """Power-on / reset: boot-up message, then PRE-OPERATIONAL."""
        self.nmt_state = NMT_BOOT
        self.heartbeat(now)  # boot-up message: heartbeat with state 0
        self.nmt_state = NMT_PRE_OPERATIONAL
        self.consumer_seen_ns = 0

    def on_nmt(self, data: bytes, now: int) -> None:
        if self.silent or len(data) != 2:
            return
        cmd, target = data[0], data[1]
        if target not in (0, self.node_id):
            return
        self.counters["nmt_rx"] += 1
        if cmd in (0x81, 0x82):
            self.reset(now, application=cmd == 0x81)
            return
        new = _NMT_CMD.get(cmd)
        if new is not None and new != self.nmt_state:
            old = self.nmt_state
            self.nmt_state = new
            self.on_nmt_change(old, new, now)
            self.heartbeat(now)  # report the new state at once

    def on_nmt_change(self, old: int, new: int, now: int) -> None:
        """Hook for devices (the amplifier zeroes its output when leaving OPERATIONAL)."""

    def reset(self, now: int, application: bool = True) -> None:
        """NMT reset node (application) or reset communication: defaults, boot-up."""
        if application:
            self.local.data_store.clear()
        else:
            for index in [i for i in self.local.data_store if 0x1000 <= i < 0x2000]:
                del self.local.data_store[index]
        self.hb_period_ms = self._od_int(0x1017, 0)
        self.consumer = None
        self.boot(now)

    def _on_sdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            if self.silent:
                return
            self.counters["sdo_rx"] += 1
            self.local.sdo.on_request(can_id, data, timestamp)

    # -- object dictionary hooks --
    def _on_write(self, index: int, subindex: int, od, data: bytes) -> None:
        if index == 0x1017:
            self.hb_period_ms = struct.unpack("<H", data[:2])[0]
        elif index == 0x1016 and subindex == 1:
            value = struct.unpack("<I", data[:4])[0]
            producer, ms = value >> 16 & 0x7F, value & 0xFFFF
            if self.consumer is not None:
                try:
                    self.network.unsubscribe(0x700 + self.consumer[0], self._on_consumed_hb)
                except (KeyError, ValueError):
                    pass
            self.consumer = (producer, ms) if producer and ms else None
            self.consumer_seen_ns = 0
            if self.consumer is not None:
                self.network.subscribe(0x700 + producer, self._on_consumed_hb)

    def _on_read(self, index: int, subindex: int, od):
        if index == 0x1001:
            return self.error_register
        return None

    def _on_consumed_hb(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            if not self.silent:
                self.consumer_seen_ns = self.clock()

    # -- time --
    def tick(self, now: int) -> None:
        """Heartbeat production, heartbeat consumer, end of an injected silence."""
        if self.silent and self.silent_until_ns and now >= self.silent_until_ns:
            self.silent = False
            self.silent_until_ns = 0
        if self.hb_period_ms and now - self._last_hb_ns >= self.hb_period_ms * 1_000_000:
            self.heartbeat(now)
        hb_at = self._heartbeat_deadline()
        if hb_at is not None and now > hb_at:
            self.consumer_seen_ns = 0  # re-armed by the next heartbeat
            self.on_heartbeat_lost(now)

    def _heartbeat_deadline(self) -> int | None:
        """When the consumed heartbeat runs out (ns), while one is being watched."""
        if self.consumer is None or not self.consumer_seen_ns:
            return None
        return self.consumer_seen_ns + self.consumer[1] * 1_000_000

    def on_heartbeat_lost(self, now: int) -> None:
        """The consumed heartbeat (the daemon's) is late: EMCY 0x8130."""
        self.emcy(cia402.FAULT_CODES["daemon_heartbeat_lost"])


class EmulatedAmplifier(EmulatedNode):
    """One CiA 402 current-mode amplifier driving one thruster of a ThrusterBank.

    The received target torque (1/1000 of rated torque) becomes the thruster's thrust command
    through the linear steady-state calibration ``thrust = target × thrust_per_permille_n``
    (rated torque ⇔ the thruster's ``max_thrust_n``); the velocity actual it reports is the
    bank's propeller speed ω in ``velocity_rad_s_per_count`` units.

    Parameters
    ----------
    network, node_id, eds
        As :class:`EmulatedNode`.
    index : int
        The thruster's index in the bank.
    thrust_per_permille_n : float
        Calibration (N per 1/1000 of rated torque).
    velocity_rad_s_per_count : float
        Unit of 0x606C.
    history : int
        How many applied targets to remember (for replay comparisons).
    """

    def __init__(self, network: canopen.Network, node_id: int, eds: Path, index: int,
                 thrust_per_permille_n: float, velocity_rad_s_per_count: float = 0.001,
                 history: int = 20_000, **kw) -> None:
        super().__init__(network, node_id, eds, **kw)
        self.index = index
        self.thrust_per_permille_n = thrust_per_permille_n
        self.velocity_scale = velocity_rad_s_per_count
        self.local.rpdo.read(from_od=True)
        self.local.tpdo.read(from_od=True)
        for m in self.local.tpdo.map.values():
            if m.enabled:  # we send our TPDOs; never let an echo or a replay overwrite them
                network.unsubscribe(m.cob_id, m.on_message)
        self.rpdo_maps = [m for m in self.local.rpdo.map.values() if m.enabled]
        for m in self.rpdo_maps:
            m.add_callback(self._on_rpdo)
        self.tpdo_maps = [m for m in self.local.tpdo.map.values() if m.enabled]
        self.state = cia402.NOT_READY
        self.mode = self._od_int(0x6060, 0) or cia402.MODE_CYCLIC_SYNC_TORQUE
        self.command_timeout_ms = self._od_int(0x1400, 5)
        self.max_torque = self._od_int(0x6072, 0) or 1000
        self.controlword = 0
        self.pending_cw: int | None = None
        self.pending_target = 0
        self.applied = 0  # target torque in force (1/1000 rated)
        self.last_rpdo_ns = 0
        self.armed_ns = 0
        self.error_code = 0
        self.persistent_fault = False
        self.omega = 0.0  # set by the owner from the bank before each TPDO
        self.history: deque[tuple[int, int]] = deque(maxlen=history)
        self.last_timeout_ms: float | None = None
        self.last_timeout_ns = 0
        self.counters.update(rpdo_rx=0, sync_rx=0, tpdo_tx=0, rpdo_missed=0, timeouts=0,
                             faults=0, fault_resets=0, rpdo_bad=0)
        self._rpdo_since_sync = False
        self._sync_count = 0

    # -- frames --
    def _on_rpdo(self, pdo) -> None:
        now = self.clock()
        with self.lock:
            if self.silent or self.nmt_state != NMT_OPERATIONAL:
                return
            try:
                cw = int(pdo[0x6040].raw)
                target = int(pdo[0x6071].raw)
            except Exception:  # noqa: BLE001 - a malformed RPDO is counted, not fatal
                self.counters["rpdo_bad"] += 1
                return
            self.counters["rpdo_rx"] += 1
            self.pending_cw, self.pending_target = cw, target
            self.last_rpdo_ns = now
            self._rpdo_since_sync = True

    def on_sync(self, now: int) -> None:
        """Apply the RPDO received since the last SYNC, then send the TPDOs."""
        if self.silent or self.nmt_state != NMT_OPERATIONAL:
            return
        self.counters["sync_rx"] += 1
        if not self._rpdo_since_sync and self.state == cia402.OPERATION_ENABLED:
            self.counters["rpdo_missed"] += 1
        self._rpdo_since_sync = False
        if self.pending_cw is not None:
            self.apply_controlword(self.pending_cw, now)
            self.pending_cw = None
        if self.state == cia402.OPERATION_ENABLED:
            self.applied = max(-self.max_torque, min(self.max_torque, self.pending_target))
        else:
            self.applied = 0
        self.history.append((now, self.applied))
        self._sync_count += 1
        for m in self.tpdo_maps:
            if m.trans_type is not None and 1 <= m.trans_type <= 240 \
                    and self._sync_count % m.trans_type == 0:
                self._transmit(m)

    def _transmit(self, m) -> None:
        for var in m.map:
            value = self.od_value(var.index, var.subindex)
            if value is not None:
                var.raw = value
        try:
            m.transmit()
            self.counters["tpdo_tx"] += 1
        except FrameDropped:
            self.counters["dropped_tx"] += 1

    def apply_controlword(self, cw: int, now: int) -> None:
        command = cia402.command_from_controlword(cw, self.controlword)
        self.controlword = cw
        old = self.state
        if command == cia402.CMD_FAULT_RESET and old == cia402.FAULT:
            if self.persistent_fault:
                self.emcy(self.error_code)  # still there
                return
            self.counters["fault_resets"] += 1
            self.error_code = 0
            self.emcy(0)
        new = cia402.device_next_state(old, command)
        if new != old:
            self.state = new
            if new == cia402.OPERATION_ENABLED:
                self.armed_ns = now
                self.last_rpdo_ns = max(self.last_rpdo_ns, now)

    # -- faults --
    def fault(self, code: int, now: int, persistent: bool = False,
              data: bytes = b"") -> None:
        """Fault reaction: output zero at once, FAULT, EMCY ``code``."""
        self.applied = 0
        self.pending_target = 0
        self.state = cia402.FAULT
        self.error_code = code
        self.persistent_fault = persistent
        self.counters["faults"] += 1
        self.emcy(code, data)

    def on_heartbeat_lost(self, now: int) -> None:
        if self.state in (cia402.OPERATION_ENABLED, cia402.SWITCHED_ON,
                          cia402.READY_TO_SWITCH_ON, cia402.QUICK_STOP_ACTIVE):
            self.fault(cia402.FAULT_CODES["daemon_heartbeat_lost"], now)
        else:
            super().on_heartbeat_lost(now)

    def on_nmt_change(self, old: int, new: int, now: int) -> None:
        if old == NMT_OPERATIONAL and self.state not in (cia402.FAULT, cia402.NOT_READY):
            self.applied = 0
            self.state = cia402.SWITCH_ON_DISABLED  # no PDO, no torque

    def reset(self, now: int, application: bool = True) -> None:
        super().reset(now, application)
        self.state = cia402.SWITCH_ON_DISABLED
        self.applied = self.pending_target = 0
        self.pending_cw = None
        self.controlword = 0
        self.error_code = 0
        self.persistent_fault = False
        self.mode = self._od_int(0x6060, 0) or cia402.MODE_CYCLIC_SYNC_TORQUE
        self.command_timeout_ms = self._od_int(0x1400, 5)
        self.max_torque = self._od_int(0x6072, 0) or 1000

    def boot(self, now: int) -> None:
        super().boot(now)
        self.state = cia402.SWITCH_ON_DISABLED  # transition 1 is automatic

    def tick(self, now: int) -> None:
        # Both the command timeout and the consumed heartbeat may have run out by a late tick
        # (the emulator's thread delayed on a loaded machine): the one that ran out first
        # faults the drive, as on a drive whose timers run on their own.
        timeout_at = self._command_deadline()
        hb_at = self._heartbeat_deadline()
        if timeout_at is not None and now > timeout_at and (hb_at is None or timeout_at <= hb_at):
            self._command_timeout(now)
        super().tick(now)
        timeout_at = self._command_deadline()
        if timeout_at is not None and now > timeout_at:
            self._command_timeout(now)

    def _command_deadline(self) -> int | None:
        """When the command timeout runs out (ns), while operation is enabled."""
        if self.state != cia402.OPERATION_ENABLED or not self.command_timeout_ms:
            return None
        return max(self.last_rpdo_ns, self.armed_ns) + self.command_timeout_ms * 1_000_000

    def _command_timeout(self, now: int) -> None:
        """No command within the timeout: FAULT, EMCY 0x8250 with the milliseconds since the
        last command in its manufacturer bytes (u16)."""
        ms = (now - max(self.last_rpdo_ns, self.armed_ns)) / 1e6
        self.last_timeout_ms = ms
        self.last_timeout_ns = now
        self.counters["timeouts"] += 1
        self.fault(cia402.FAULT_CODES["command_timeout"], now,
                   data=struct.pack("<H", min(int(round(ms)), 0xFFFF)))

    # -- output --
    def thrust_command_n(self) -> float:
        """What the amplifier drives: the applied current as a steady-state thrust (N)."""
        if self.state != cia402.OPERATION_ENABLED:
            return 0.0
        return self.applied * self.thrust_per_permille_n

    # -- object dictionary --
    def od_value(self, index: int, subindex: int = 0):
        """Live value of a process object (None: take the stored/default value)."""
        if index == 0x6041:
            return cia402.statusword_for(self.state,
                                         internal_limit=abs(self.pending_target) > self.max_torque)
        if index == 0x6077 or index == 0x6078:
            return int(self.applied if self.state == cia402.OPERATION_ENABLED else 0)
        if index == 0x606C:
            v = int(round(self.omega / self.velocity_scale))
            return max(-2**31, min(2**31 - 1, v))
        if index == 0x6061:
            return self.mode
        if index == 0x603F:
            return self.error_code
        if index == 0x6040:
            return self.controlword
        if index == 0x6071:
            return self.pending_target
        if index == 0x1001:
            return self.error_register
        return None

    def _on_read(self, index: int, subindex: int, od):
        return self.od_value(index, subindex)

    def _on_write(self, index: int, subindex: int, od, data: bytes) -> None:
        super()._on_write(index, subindex, od, data)
        if index == 0x6060:
            mode = struct.unpack("<b", data[:1])[0]
            if mode not in cia402.MODES.values():
                raise SdoAbortedError(0x06090030)  # value range of parameter exceeded
            self.mode = mode
        elif self.rpdo_maps and index == self.rpdo_maps[0].com_record.od.index \
                and subindex == 5:
            self.command_timeout_ms = struct.unpack("<H", data[:2])[0]
        elif index == 0x6072:
            self.max_torque = struct.unpack("<H", data[:2])[0]
        elif index == 0x6040:
            self.apply_controlword(struct.unpack("<H", data[:2])[0], self.clock())

    def snapshot(self, bank=None) -> dict:
        """JSON-friendly state of this node."""
        out = {
            "node_id": self.node_id,
            "state": self.state,
            "nmt": NMT_NAMES.get(self.nmt_state, str(self.nmt_state)),
            "silent": self.silent,
            "applied_permille": self.applied,
            "thrust_command_n": self.thrust_command_n(),
            "error_code": self.error_code,
            "command_timeout_ms": self.command_timeout_ms,
            "last_timeout_ms": self.last_timeout_ms,
            "mode": self.mode,
            **self.counters,
        }
        if bank is not None:
            i = self.index
            out.update(omega_rad_s=float(bank.omega[i]), thrust_n=float(bank.thrust[i]),
                       health=float(bank.health[i]))
        return out
