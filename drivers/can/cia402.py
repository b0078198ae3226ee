"""CiA 402 drive profile and CiA 301 EMCY codes — pure codecs, no I/O.

Both sides of the bus use this module: the amplifier driver (:mod:`drivers.can.amplifier`)
decodes statuswords and chooses controlwords, and the emulated amplifiers
(:mod:`sim_bridge.amplifiers`) decode controlwords and encode statuswords. One table, one
truth.

Power state machine (CiA 402, Fig. "State machine of the drive")::

    NOT READY ──(1, automatic)──> SWITCH ON DISABLED ──Shutdown (2)──> READY TO SWITCH ON
    READY ──Switch on (3)──> SWITCHED ON ──Enable operation (4)──> OPERATION ENABLED
    OPERATION ENABLED ──Disable op. (5)──> SWITCHED ON ──Shutdown (6)──> READY
    OPERATION ENABLED ──Quick stop (11)──> QUICK STOP ACTIVE ──Disable voltage (12)──> SW. ON DIS.
    any ──fault──> FAULT REACTION ACTIVE ──(14, auto)──> FAULT ──Fault reset (15)──> SW. ON DIS.

Only in OPERATION ENABLED does a drive apply its target; everywhere else its output is zero.
"""

from __future__ import annotations

from collections.abc import Mapping

# --- states --------------------------------------------------------------------------------

NOT_READY = "not_ready_to_switch_on"
SWITCH_ON_DISABLED = "switch_on_disabled"
READY_TO_SWITCH_ON = "ready_to_switch_on"
SWITCHED_ON = "switched_on"
OPERATION_ENABLED = "operation_enabled"
QUICK_STOP_ACTIVE = "quick_stop_active"
FAULT_REACTION_ACTIVE = "fault_reaction_active"
FAULT = "fault"
UNKNOWN = "unknown"

STATES = (NOT_READY, SWITCH_ON_DISABLED, READY_TO_SWITCH_ON, SWITCHED_ON, OPERATION_ENABLED,
          QUICK_STOP_ACTIVE, FAULT_REACTION_ACTIVE, FAULT)

# (mask, value, state) — statusword bits 0-3, 5, 6 (CiA 402 Table "Statusword state coding").
_SW_DECODE = (
    (0x004F, 0x0000, NOT_READY),
    (0x004F, 0x0040, SWITCH_ON_DISABLED),
    (0x006F, 0x0021, READY_TO_SWITCH_ON),
    (0x006F, 0x0023, SWITCHED_ON),
    (0x006F, 0x0027, OPERATION_ENABLED),
    (0x006F, 0x0007, QUICK_STOP_ACTIVE),
    (0x004F, 0x000F, FAULT_REACTION_ACTIVE),
    (0x004F, 0x0008, FAULT),
)

SW_VOLTAGE_ENABLED = 0x0010
SW_WARNING = 0x0080
SW_REMOTE = 0x0200
SW_TARGET_REACHED = 0x0400
SW_INTERNAL_LIMIT = 0x0800

_SW_ENCODE = {
    NOT_READY: 0x0000,
    SWITCH_ON_DISABLED: 0x0040,
    READY_TO_SWITCH_ON: 0x0021 | SW_VOLTAGE_ENABLED,
    SWITCHED_ON: 0x0023 | SW_VOLTAGE_ENABLED,
    OPERATION_ENABLED: 0x0027 | SW_VOLTAGE_ENABLED,
    QUICK_STOP_ACTIVE: 0x0007 | SW_VOLTAGE_ENABLED,
    FAULT_REACTION_ACTIVE: 0x000F,
    FAULT: 0x0008,
}


def state_from_statusword(statusword: int) -> str:
    """Name of the CiA 402 power state encoded in ``statusword`` (0x6041).

    Parameters
    ----------
    statusword : int
        The 16-bit statusword.

    Returns
    -------
    str
        One of :data:`STATES`, or :data:`UNKNOWN` for a bit pattern the profile does not
        define.
    """
    for mask, value, state in _SW_DECODE:
        if statusword & mask == value:
            return state
    return UNKNOWN


def statusword_for(state: str, *, warning: bool = False, target_reached: bool = False,
                   internal_limit: bool = False) -> int:
    """Statusword (0x6041) a drive reports in ``state`` (device side; the emulators use it).

    Bit 9 (remote: the drive follows the controlword) is always set.
    """
    sw = _SW_ENCODE[state] | SW_REMOTE
    if warning:
        sw |= SW_WARNING
    if target_reached:
        sw |= SW_TARGET_REACHED
    if internal_limit:
        sw |= SW_INTERNAL_LIMIT
    return sw


# --- controlword -----------------------------------------------------------------------------

CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_DISABLE_OPERATION = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_FAULT_RESET = 0x0080

CMD_SHUTDOWN = "shutdown"
CMD_SWITCH_ON = "switch_on"
CMD_ENABLE_OPERATION = "enable_operation"
CMD_DISABLE_VOLTAGE = "disable_voltage"
CMD_QUICK_STOP = "quick_stop"
CMD_FAULT_RESET = "fault_reset"
CMD_NONE = "none"


def command_from_controlword(controlword: int, previous: int = 0) -> str:
    """Device command encoded by ``controlword`` (0x6040), CiA 402 Table "Command coding".

    ``previous`` is the controlword received before; the fault reset command is the rising
    edge of bit 7, so it needs both.
    """
    if controlword & 0x0080:
        return CMD_FAULT_RESET if not previous & 0x0080 else CMD_NONE
    if controlword & 0x0002 == 0:
        return CMD_DISABLE_VOLTAGE
    if controlword & 0x0006 == 0x0002:
        return CMD_QUICK_STOP
    if controlword & 0x0007 == 0x0006:
        return CMD_SHUTDOWN
    if controlword & 0x000F == 0x0007:
        return CMD_SWITCH_ON  # also "disable operation" from OPERATION ENABLED
    if controlword & 0x000F == 0x000F:
        return CMD_ENABLE_OPERATION
    return CMD_NONE


def device_next_state(state: str, command: str) -> str:
    """Transition of the drive's power state machine for one received command (device side).

    Automatic transitions (NOT READY → SWITCH ON DISABLED, FAULT REACTION ACTIVE → FAULT) are
    the device's own business and are not handled here.
    """
    if command == CMD_FAULT_RESET:
        return SWITCH_ON_DISABLED if state == FAULT else state
    if state in (FAULT, FAULT_REACTION_ACTIVE, NOT_READY):
        return state
    if command == CMD_DISABLE_VOLTAGE:
        return SWITCH_ON_DISABLED
    if command == CMD_QUICK_STOP:
        if state == OPERATION_ENABLED:
            return QUICK_STOP_ACTIVE
        if state == QUICK_STOP_ACTIVE:
            return QUICK_STOP_ACTIVE
        return SWITCH_ON_DISABLED
    if command == CMD_SHUTDOWN:
        if state in (SWITCH_ON_DISABLED, SWITCHED_ON, OPERATION_ENABLED):
            return READY_TO_SWITCH_ON
        return state
    if command == CMD_SWITCH_ON:
        if state in (READY_TO_SWITCH_ON, OPERATION_ENABLED):
            return SWITCHED_ON
        return state
    if command == CMD_ENABLE_OPERATION:
        if state in (SWITCHED_ON, QUICK_STOP_ACTIVE):
            return OPERATION_ENABLED
        if state == READY_TO_SWITCH_ON:
            return SWITCHED_ON  # "switch on" is implied; enable on the next command
        return state
    return state


GOAL_ENABLED = "enabled"
GOAL_DISABLED = "disabled"
GOAL_QUICK_STOP = "quick_stop"
GOALS = (GOAL_ENABLED, GOAL_DISABLED, GOAL_QUICK_STOP)


def master_controlword(state: str, goal: str, *, fault_reset: bool = False,
                       previous: int = 0) -> int:
    """Controlword (master side) that moves a drive in ``state`` one step towards ``goal``.

    Parameters
    ----------
    state : str
        The drive's power state as last reported by its statusword.
    goal : str
        :data:`GOAL_ENABLED`, :data:`GOAL_DISABLED` or :data:`GOAL_QUICK_STOP`.
    fault_reset : bool
        A fault reset was requested; in FAULT the controlword toggles bit 7 so that each
        second cycle presents a rising edge.
    previous : int
        The controlword sent last cycle (for the bit-7 edge).

    Notes
    -----
    A drive in FAULT is never reset without an explicit request: re-enabling motors after a
    fault is the daemon's decision, not the driver's.
    """
    if state == FAULT:
        if fault_reset and not previous & CW_FAULT_RESET:
            return CW_FAULT_RESET
        return CW_DISABLE_VOLTAGE
    if goal == GOAL_ENABLED:
        return {
            SWITCH_ON_DISABLED: CW_SHUTDOWN,
            READY_TO_SWITCH_ON: CW_SWITCH_ON,
            SWITCHED_ON: CW_ENABLE_OPERATION,
            OPERATION_ENABLED: CW_ENABLE_OPERATION,
        }.get(state, CW_DISABLE_VOLTAGE)
    if goal == GOAL_QUICK_STOP and state in (OPERATION_ENABLED, QUICK_STOP_ACTIVE):
        return CW_QUICK_STOP
    return CW_DISABLE_VOLTAGE


# --- modes of operation (0x6060) -------------------------------------------------------------

MODE_PROFILE_TORQUE = 4
MODE_CYCLIC_SYNC_TORQUE = 10
MODES = {"pt": MODE_PROFILE_TORQUE, "cst": MODE_CYCLIC_SYNC_TORQUE}

# --- EMCY (CiA 301 §7.2.7, CiA 402 error codes) ----------------------------------------------

#: EMCY error code → fault name. The emulators inject faults by these names.
EMCY_FAULTS: Mapping[int, str] = {
    0x1000: "generic_error",
    0x2310: "overcurrent",
    0x2320: "short_circuit",
    0x3210: "overvoltage",
    0x3220: "undervoltage",
    0x4210: "overtemperature",
    0x4310: "drive_overtemperature",
    0x5530: "eeprom_fault",
    0x6100: "internal_software",
    0x7121: "motor_blocked",
    0x7122: "motor_commutation",
    0x7305: "encoder_fault",
    0x8110: "can_overrun",
    0x8120: "can_error_passive",
    0x8130: "daemon_heartbeat_lost",  # the drive lost the heartbeat it consumes
    0x8140: "bus_off_recovered",
    0x8210: "pdo_length_error",
    0x8220: "pdo_length_exceeded",
    0x8250: "command_timeout",
    0xFF00: "device_specific",
}
FAULT_CODES: Mapping[str, int] = {name: code for code, name in EMCY_FAULTS.items()}

#: CiA 301 error register (0x1001) bit for each EMCY class (high nibble of the code).
_ERROR_REGISTER_BIT = {0x1: 0x01, 0x2: 0x02, 0x3: 0x04, 0x4: 0x08, 0x8: 0x10, 0x7: 0x20,
                       0xF: 0x80}

_EMCY_CLASSES = (
    (0xFF00, 0x0000, "no_error"), (0xFF00, 0x1000, "generic"), (0xF000, 0x2000, "current"),
    (0xF000, 0x3000, "voltage"), (0xF000, 0x4000, "temperature"),
    (0xFF00, 0x5000, "hardware"), (0xF000, 0x6000, "software"), (0xFF00, 0x7000, "module"),
    (0xF000, 0x8000, "communication"), (0xFF00, 0x9000, "external"),
    (0xFF00, 0xF000, "additional"), (0xFF00, 0xFF00, "device_specific"),
)


def emcy_fault_name(code: int) -> str:
    """Fault name of an EMCY error code: the table name, else ``"<class>_0xCODE"``."""
    name = EMCY_FAULTS.get(code)
    if name is not None:
        return name
    for mask, value, cls in _EMCY_CLASSES:
        if code & mask == value:
            return f"{cls}_0x{code:04x}"
    return f"emcy_0x{code:04x}"


def error_register_for(code: int) -> int:
    """CiA 301 error register (0x1001) value that accompanies EMCY ``code``."""
    if code == 0:
        return 0
    return 0x01 | _ERROR_REGISTER_BIT.get(code >> 12, 0x80)
