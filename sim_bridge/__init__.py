"""The simulated vehicle behind real wire protocols (plant, thrusters, instrument and amplifier
emulators)."""

import uvd  # noqa: F401  (first: it chooses numba's cache directory, see uvd/_jitcache.py)
