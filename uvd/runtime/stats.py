"""A constant-memory log-linear histogram of nanosecond durations (HdrHistogram-like).

Values below 2^B ns (B = ``sub_bits``, 128 ns by default) are counted exactly; above, each
power of two is split into 2^(B−1) equal buckets, so a quantile is reported to within
1/2^(B−1) (< 1.6 %) of its value. Recording is O(1) and allocation-free — cheap enough for
every cycle of a 1 kHz loop — and memory is fixed (a few thousand counters) however long the
daemon runs. The maximum, minimum and count are exact.
"""

from __future__ import annotations

import math

__all__ = ["Histogram"]


class Histogram:
    """Histogram of non-negative integers (ns); negatives are counted and recorded as 0.

    Parameters
    ----------
    sub_bits : int
        B above: resolution 2^−(B−1) relative; values < 2^B exact.
    """

    __slots__ = ("_B", "_lin", "_half", "counts", "count", "total", "max", "min", "negatives")

    def __init__(self, sub_bits: int = 7) -> None:
        if not 2 <= sub_bits <= 16:
            raise ValueError("sub_bits must be in [2, 16]")
        self._B = sub_bits
        self._lin = 1 << sub_bits
        self._half = 1 << (sub_bits - 1)
        self.counts = [0] * (self._lin + 64 * self._half)
        self.count = 0
        self.total = 0
        self.max = 0
        self.min = 0
        self.negatives = 0

    def _index(self, v: int) -> int:
        if v < self._lin:
            return v
        shift = v.bit_length() - self._B
        return self._lin + (shift - 1) * self._half + ((v >> shift) - self._half)

    def bucket_bounds(self, idx: int) -> tuple[int, int]:
        """Half-open value range ``[lo, hi)`` of bucket ``idx``."""
        if idx < self._lin:
            return idx, idx + 1
        j = idx - self._lin
        shift = j // self._half + 1
        top = j % self._half + self._half
        return top << shift, (top + 1) << shift

    def record(self, value_ns: int) -> None:
        """Count one value (integer ns)."""
        v = int(value_ns)
        if v < 0:
            self.negatives += 1
            v = 0
        self.counts[self._index(v)] += 1
        if self.count == 0:
            self.max = self.min = v
        elif v > self.max:
            self.max = v
        elif v < self.min:
            self.min = v
        self.count += 1
        self.total += v

    def percentile(self, q: float) -> float:
        """The q-th percentile (0–100, nearest rank) in ns; NaN when empty."""
        if self.count == 0:
            return float("nan")
        if q >= 100:
            return float(self.max)
        rank = min(self.count, max(1, math.ceil(q * self.count / 100.0 - 1e-9)))
        seen = 0
        for idx, c in enumerate(self.counts):
            if c:
                seen += c
                if seen >= rank:
                    lo, hi = self.bucket_bounds(idx)
                    mid = lo if hi - lo == 1 else (lo + hi - 1) / 2
                    return float(min(max(mid, self.min), self.max))
        return float(self.max)

    def mean(self) -> float:
        """Arithmetic mean (ns); NaN when empty."""
        return self.total / self.count if self.count else float("nan")

    def summary_us(self, qs: tuple[float, ...] = (50, 99, 99.9)) -> dict[str, float]:
        """``{"p50": …, "p99": …, "p999": …, "max": …, "mean": …}`` in microseconds."""
        out: dict[str, float] = {}
        for q in qs:
            name = "p" + (f"{q:g}".replace(".", ""))
            out[name] = self.percentile(q) / 1e3
        out["max"] = float(self.max) / 1e3 if self.count else float("nan")
        out["mean"] = self.mean() / 1e3
        out["n"] = self.count
        return out

    def reset(self) -> None:
        """Forget everything recorded."""
        for i in range(len(self.counts)):
            self.counts[i] = 0
        self.count = self.total = self.max = self.min = self.negatives = 0
