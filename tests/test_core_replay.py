"""The compiled glue of the control cycle gives the outputs of the plain-numpy cycle.

``tests/data/core_replay.npz`` was recorded with the cycle as it was before its Python glue
(finite checks, applied wrench, allocation, navigation assembly, estimator and controller
wrappers) was moved into compiled kernels; see :mod:`core_replay` for the scenario.
"""

import core_replay
import numpy as np
import pytest

DATA = np.load(__file__.rsplit("/", 1)[0] + "/data/core_replay.npz")


@pytest.mark.parametrize("name", core_replay.SCENARIOS)
def test_replay_matches_the_recorded_plain_numpy_cycle(name):
    got = core_replay.run(name)
    for key in core_replay.FIELDS:
        want = DATA[f"{name}/{key}"]
        have = got[key]
        assert have.shape == want.shape, key
        if want.dtype.kind in "US?b":
            np.testing.assert_array_equal(have, want, err_msg=key)
        else:
            scale = np.maximum(np.abs(want), 1.0)
            err = np.max(np.abs(have - want) / scale) if want.size else 0.0
            assert err <= 1e-12, f"{name} {key}: relative difference {err:.3g}"
