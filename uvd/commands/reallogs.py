"""``--gains`` of ``uvd identify --profile`` (the rotational law's four gains or the 6-DOF
law's five)."""

from __future__ import annotations

from uvd.errors import ConfigError


def parse_gains(text, n: int):
    """--gains a,g1,..: 4 values for the rotational law, 5 for the 6-DOF one."""
    from uvd.estimation.aid import AID3Gains, AID6Gains

    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError as exc:
        raise ConfigError(f"--gains: not numbers: {text!r}") from exc
    want = 4 if n == 3 else 5
    if len(vals) != want:
        raise ConfigError(f"--gains needs {want} values for the "
                          f"{'rotational' if n == 3 else '6-DOF'} law; got {len(vals)}")
    try:
        return AID3Gains(*vals) if n == 3 else AID6Gains(*vals)
    except ValueError as exc:
        raise ConfigError(f"--gains: {exc}") from exc

