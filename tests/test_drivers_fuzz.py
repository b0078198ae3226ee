"""10 000 random and mutated byte streams per codec: no crash, no hang, resync on the next frame.

Each stream is ``garbage + valid frame`` where the garbage is random bytes, a damaged copy of
a real frame, header fragments, or a mix, fed to a :class:`~drivers.framing.StreamDecoder` in
random chunk sizes. Hypothesis' per-example overhead is a few ms on the CI machine, so each of
the ``N_EXAMPLES`` hypothesis examples checks one hypothesis-built stream plus
``PER_EXAMPLE - 1`` streams from a ``random.Random`` seeded by hypothesis: N_EXAMPLES ×
PER_EXAMPLE = 10 000 streams per codec in a few seconds. Asserted for every stream:

* nothing raises from the stream decoder (it counts and drops), and ``codec.decode`` of the
  garbage raises nothing but :class:`~uvd.errors.FrameError` (ChecksumError is one);
* the valid frame after the garbage is decoded — the last frame out is exactly it;
* every input byte is accounted for: in a delivered frame or counted as dropped.
"""

from __future__ import annotations

import random
import time

import pytest
from driver_strategies import CODECS, mutated, sample_frames
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.framing import StreamDecoder
from uvd.errors import FrameError

N_STREAMS = 10_000
PER_EXAMPLE = 20
N_EXAMPLES = N_STREAMS // PER_EXAMPLE
FUZZ = settings(max_examples=N_EXAMPLES, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _rng_mutate(rng: random.Random, frame: bytes) -> bytes:
    b = bytearray(frame)
    for _ in range(rng.randint(1, 4)):
        if not b:
            break
        op = rng.choice(("flip", "delete", "insert", "cut", "repeat", "byte"))
        i = rng.randrange(len(b))
        if op == "flip":
            b[i] ^= 1 << rng.randrange(8)
        elif op == "delete":
            del b[i]
        elif op == "insert":
            b.insert(i, rng.randrange(256))
        elif op == "cut":
            del b[i:]
        elif op == "repeat":
            j = rng.randint(i, min(len(b), i + 16))
            b[i:i] = b[i:j]
        else:
            b[i] = rng.randrange(256)
    return bytes(b)


def _rng_stream(rng: random.Random, frames: list[bytes]):
    """The same kinds of stream as :func:`streams`, from a seeded generator."""
    target = rng.choice(frames)
    kind = rng.choice(("random", "mutated", "both", "sync-noise"))
    garbage = b""
    if kind in ("random", "both"):
        garbage += rng.randbytes(rng.randint(0, 200))
    if kind in ("mutated", "both"):
        garbage += _rng_mutate(rng, rng.choice(frames))
    if kind == "sync-noise":
        garbage = b"".join(f[:rng.randint(1, min(len(f), 40))]
                           for f in rng.choices(frames, k=rng.randint(1, 4)))
    chunks = [rng.randint(1, 512) for _ in range(rng.randint(1, 6))]
    return garbage, target, chunks


@st.composite
def streams(draw, frames: list[bytes]):
    target = draw(st.sampled_from(frames))
    kind = draw(st.sampled_from(["random", "mutated", "both", "sync-noise"]))
    garbage = b""
    if kind in ("random", "both"):
        garbage += draw(st.binary(max_size=200))
    if kind in ("mutated", "both"):
        garbage += draw(mutated(draw(st.sampled_from(frames))))
    if kind == "sync-noise":  # sync bytes and header fragments, the hardest garbage
        pieces = [f[:draw(st.integers(1, min(len(f), 40)))] for f in
                  draw(st.lists(st.sampled_from(frames), min_size=1, max_size=4))]
        garbage = b"".join(pieces)
    chunks = draw(st.lists(st.integers(1, 512), min_size=1, max_size=6))
    return garbage, target, chunks


def _check(codec_name: str, frames: list[bytes], garbage: bytes, target: bytes, chunks):
    codec = CODECS[codec_name]()
    try:
        codec.decode(garbage)
    except FrameError:
        pass
    stream = garbage + target
    dec = StreamDecoder(codec, keep_raw=True)
    out = []
    i = k = 0
    while i < len(stream):  # bounded: every pass consumes at least one byte
        n = chunks[k % len(chunks)]
        out += dec.feed(stream[i:i + n])
        i += n
        k += 1
    out += dec.finish()
    assert out, "the valid frame after the garbage was not decoded"
    assert out[-1][1] == target
    c = dec.counters
    assert sum(len(raw) for _, raw in out) + c.bytes_dropped == len(stream) == c.bytes_in
    assert dec.buffered == 0


def _fuzz(codec_name: str):
    frames = sample_frames(codec_name)
    assert frames
    count = [0]

    @FUZZ
    @given(streams(frames), st.integers(0, 2**32 - 1))
    def run(case, seed):
        count[0] += 1
        _check(codec_name, frames, *case)
        rng = random.Random(seed)
        for _ in range(PER_EXAMPLE - 1):
            garbage, target, chunks = _rng_stream(rng, frames)
            count[0] += 1
            try:
                _check(codec_name, frames, garbage, target, chunks)
            except AssertionError as exc:
                raise AssertionError(f"stream garbage={garbage.hex()} target={target.hex()} "
                                     f"chunks={chunks}: {exc}") from exc

    t0 = time.monotonic()
    run()
    assert count[0] >= N_STREAMS
    return time.monotonic() - t0


@pytest.mark.parametrize("codec_name", ["pd0", "phins-stdbin", "phins-ascii", "digiquartz"])
def test_fuzz_streams_resync(codec_name):
    _fuzz(codec_name)


def test_pd0_false_sync_whose_checksum_sums_right_is_not_a_frame():
    """Found by the fuzz test on CI: garbage ending in a damaged ensemble header whose declared
    length reaches into the next, valid ensemble, with a 16-bit sum that matched by chance.
    Its second data type is not the variable leader, so it is a frame error, and the valid
    ensemble behind it is decoded."""
    garbage = bytes.fromhex("7f7fbc01000612004c008800020140017e010000220b4b42007f7fae01000816"
                            "0051007f00c100e30005")
    target = bytes.fromhex("7f7fae010008160051007f00c100e3000501270178010000130d4b42001a0408"
                           "040032003c0001400519e8030000001794110000011d75003500010532000b00"
                           "0000000000000000000000003c5600001e800010000e0c1311120001000000dc"
                           "0500005565b9feec041f000a020000000000003e6373ffff6700950040000000"
                           "01410094fff8ff9dff5a0092ff21009afffdffe8ff2c00aeff5c00b5ff0a00ce"
                           "ff2f00bfff4500daffa10076ff2500e4ff7600dcff6300b8ff4800d7ff290027"
                           "0000026f7380887e837d818083877d82797a7c758b817d857d81827e7681817b"
                           "8281840003a6a4a5a6a4a29faf9ba099a79299889983947f8b7f857782777c75"
                           "79757a7074000400000064000000640000006400000064000000640000006400"
                           "00006400000064000604000000dc1e0005e803000000008a05a7059905a70523"
                           "0083ff2d000100ffffffff41444348646464640a000a00320000800080008000"
                           "80000000000000000000000000e2045d605d6200000000000020de07130b0000"
                           "ffffff7f00000000feba8c1dfa89b8cdffffff7ffeba8c1dfa89b8cd7e0076b8"
                           "00007e0076b810057700010011047882")
    _check("pd0", [target], garbage, target, [285, 347, 352, 463, 245])
