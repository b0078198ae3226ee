"""CiA 402 codec and state machine, EMCY naming — pure, property-tested."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.can import cia402 as c

REACHABLE = (c.SWITCH_ON_DISABLED, c.READY_TO_SWITCH_ON, c.SWITCHED_ON, c.OPERATION_ENABLED,
             c.QUICK_STOP_ACTIVE)


@given(state=st.sampled_from(c.STATES), warning=st.booleans(), reached=st.booleans(),
       limit=st.booleans())
def test_statusword_round_trip(state, warning, reached, limit):
    sw = c.statusword_for(state, warning=warning, target_reached=reached, internal_limit=limit)
    assert c.state_from_statusword(sw) == state
    assert 0 <= sw <= 0xFFFF


@given(sw=st.integers(0, 0xFFFF))
def test_every_statusword_decodes_to_a_known_name(sw):
    assert c.state_from_statusword(sw) in (*c.STATES, c.UNKNOWN)


def drive(state: str, goal: str, steps: int, fault_reset: bool = False) -> list[str]:
    """Master and device in lockstep: the master sees the state, sends, the device moves."""
    prev_cw = 0
    seen = [state]
    for _ in range(steps):
        cw = c.master_controlword(state, goal, fault_reset=fault_reset, previous=prev_cw)
        state = c.device_next_state(state, c.command_from_controlword(cw, prev_cw))
        prev_cw = cw
        seen.append(state)
    return seen


@given(start=st.sampled_from(REACHABLE))
def test_goal_enabled_reaches_operation_enabled_within_four_cycles(start):
    seen = drive(start, c.GOAL_ENABLED, 5)
    assert c.OPERATION_ENABLED in seen[:5]
    assert seen[-1] == c.OPERATION_ENABLED  # and stays there


@given(start=st.sampled_from(REACHABLE))
def test_goal_disabled_reaches_switch_on_disabled_in_one_cycle(start):
    assert drive(start, c.GOAL_DISABLED, 1)[-1] == c.SWITCH_ON_DISABLED


def test_quick_stop_from_operation_enabled():
    assert drive(c.OPERATION_ENABLED, c.GOAL_QUICK_STOP, 3)[1:] == [c.QUICK_STOP_ACTIVE] * 3


def test_fault_is_left_only_on_a_requested_reset_edge():
    assert drive(c.FAULT, c.GOAL_ENABLED, 10) == [c.FAULT] * 11  # never by itself
    seen = drive(c.FAULT, c.GOAL_ENABLED, 6, fault_reset=True)
    assert seen[1] == c.SWITCH_ON_DISABLED and seen[-1] == c.OPERATION_ENABLED


def test_fault_reset_is_the_rising_edge_of_bit_7():
    assert c.command_from_controlword(0x80, 0x00) == c.CMD_FAULT_RESET
    assert c.command_from_controlword(0x80, 0x80) == c.CMD_NONE
    assert c.command_from_controlword(0x8F, 0x0F) == c.CMD_FAULT_RESET


@pytest.mark.parametrize("cw,cmd", [(0x06, c.CMD_SHUTDOWN), (0x07, c.CMD_SWITCH_ON),
                                    (0x0F, c.CMD_ENABLE_OPERATION), (0x00, c.CMD_DISABLE_VOLTAGE),
                                    (0x02, c.CMD_QUICK_STOP), (0x0D, c.CMD_DISABLE_VOLTAGE)])
def test_controlword_command_coding(cw, cmd):
    assert c.command_from_controlword(cw) == cmd


def test_emcy_names_and_error_register():
    assert c.emcy_fault_name(0x8250) == "command_timeout"
    assert c.emcy_fault_name(0x2310) == "overcurrent"
    assert c.emcy_fault_name(0x2399) == "current_0x2399"
    assert c.emcy_fault_name(0x8F01) == "communication_0x8f01"
    assert c.FAULT_CODES["overcurrent"] == 0x2310
    assert c.error_register_for(0x2310) == 0x03  # generic + current
    assert c.error_register_for(0x4310) == 0x09  # generic + temperature
    assert c.error_register_for(0x8250) == 0x11  # generic + communication
    assert c.error_register_for(0) == 0


@given(code=st.integers(0, 0xFFFF))
def test_every_emcy_code_has_a_name(code):
    name = c.emcy_fault_name(code)
    assert name and name.isascii()
