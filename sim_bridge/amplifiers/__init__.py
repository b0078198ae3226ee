"""Emulated CiA 402 thruster amplifiers on a CAN bus (see :mod:`.emulators`)."""

from sim_bridge.amplifiers.emulators import CanEmulators
from sim_bridge.amplifiers.node import EmulatedAmplifier, EmulatedNode

__all__ = ["CanEmulators", "EmulatedAmplifier", "EmulatedNode"]
