"""Hypothesis strategies, sample frames and the real recordings (tests/data/) shared by the
driver tests (no tests here)."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import strategies as st

from drivers import digiquartz, pd0, phins_ascii, phins_stdbin
from drivers._layout import Layout
from drivers.framing import decode_bytes

#: the real recordings whose licence lets them live in the repository (tests/data/README.md)
DATA = Path(__file__).resolve().parent / "data"


def read_data(rel: str) -> bytes:
    path = DATA / rel
    if not path.is_file():
        pytest.fail(f"recording {path} is missing: it belongs to the repository "
                    f"(tests/data/README.md)")
    return path.read_bytes()


_INT_RANGES = {"B": (0, 0xFF), "H": (0, 0xFFFF), "h": (-0x8000, 0x7FFF),
               "I": (0, 0xFFFFFFFF), "i": (-0x80000000, 0x7FFFFFFF)}


def _scalar(code: str):
    c = code[-1]
    if c in _INT_RANGES:
        lo, hi = _INT_RANGES[c]
        return st.integers(lo, hi)
    if c == "f":
        return st.floats(width=32, allow_nan=False, allow_infinity=False)
    if c == "d":
        return st.floats(allow_nan=False, allow_infinity=False)
    if c == "s":
        n = int(code[:-1])
        return st.binary(min_size=n, max_size=n)
    raise ValueError(code)


def _finite(v):
    if isinstance(v, float) and not math.isfinite(v):
        return 0.0
    return v


def layout_values(lay: Layout, fixed: dict | None = None, prefix: bool = False):
    """A dict of random values for every field of ``lay`` (or a random prefix of them).

    Values come from random bytes decoded with the layout itself (every bit pattern of every
    field is reachable, and drawing one binary is much cheaper than one strategy per field);
    non-finite floats are replaced by 0 so that equality is meaningful.
    """
    names = [n for n, _ in lay.fields]
    sizes = [struct.calcsize(lay.order + code) for _, code in lay.fields]

    def build(args):
        raw, k, extra = args
        d = dict(lay.decode(raw))
        d = {n: (tuple(_finite(x) for x in v) if isinstance(v, tuple) else _finite(v))
             for n, v in d.items()}
        if fixed:
            d.update(fixed)
        if not prefix:
            k = len(names)
        out = {n: d[n] for n in names[:k]}
        # a tail shorter than the next field stays "_extra"; a longer one would be decoded
        out["_extra"] = extra[:sizes[k] - 1] if k < len(names) else b""
        return out
    return st.tuples(st.binary(min_size=lay.size, max_size=lay.size),
                     st.integers(1, len(names)), st.binary(max_size=1)).map(build)


@st.composite
def pd0_ensembles(draw) -> pd0.Pd0Ensemble:
    n_cells = draw(st.integers(0, 6))
    n_beams = 4
    fixed = draw(layout_values(pd0.FIXED_LEADER, {"id": pd0.ID_FIXED}))
    fixed["num_cells"], fixed["num_beams"] = n_cells, n_beams
    variable = draw(layout_values(pd0.VARIABLE_LEADER, {"id": pd0.ID_VARIABLE}, prefix=True))
    bt = draw(st.none() | layout_values(pd0.BOTTOM_TRACK, {"id": pd0.ID_BOTTOM_TRACK}))
    profiles = {}
    order = [pd0.ID_FIXED, pd0.ID_VARIABLE]
    for tid in draw(st.lists(st.sampled_from(sorted(pd0._PROFILE_IDS)), unique=True,
                             max_size=5)):
        dt = pd0._PROFILE_IDS[tid]
        size = n_cells * n_beams * dt.itemsize
        raw = draw(st.binary(min_size=size, max_size=size))
        profiles[tid] = np.frombuffer(raw, dtype=dt).reshape(n_cells, n_beams).copy()
        order.append(tid)
    if bt is not None:
        order.append(pd0.ID_BOTTOM_TRACK)
    other = {}
    for tid in draw(st.lists(st.integers(0x2000, 0x7FFF), unique=True, max_size=2)):
        other[tid] = draw(st.binary(max_size=20))
        order.append(tid)
    return pd0.Pd0Ensemble(fixed, variable, bt, profiles, other, tuple(order),
                           draw(st.integers(0, 255)))


@st.composite
def stdbin_frames(draw) -> phins_stdbin.StdbinFrame:
    version = draw(st.sampled_from([2, 3, 4, 5]))
    blocks = {}
    tables = [phins_stdbin.NAV_BLOCKS, phins_stdbin.EXTERNAL_BLOCKS]
    if version >= 3:
        tables.insert(1, phins_stdbin.EXT_NAV_BLOCKS)
    for table in tables:
        for bit in draw(st.lists(st.sampled_from(sorted(table)), unique=True, max_size=6)):
            name, lay = table[bit]
            d = draw(layout_values(lay))
            d.pop("_extra", None)
            blocks[name] = d
    nav_size = draw(st.integers(0, 0xFFFF)) if version >= 4 else None
    return phins_stdbin.StdbinFrame(version, 0, 0, 0, draw(st.integers(0, 0xFFFFFFFF)),
                                    draw(st.integers(0, 0xFFFFFFFF)), blocks, nav_size)


_ASCII_TEXT = st.text(alphabet=st.characters(min_codepoint=0x20, max_codepoint=0x7E,
                                             exclude_characters="$*,!\\^~"), max_size=12)


@st.composite
def phins_sentences(draw) -> phins_ascii.PhinsSentence:
    kind = draw(st.sampled_from(sorted(phins_ascii.SENTENCES)))
    names, _ = phins_ascii.SENTENCES[kind]
    if kind in ("ALGSTS", "STATUS", "HT_STS"):
        vals = [draw(st.integers(0, 0xFFFFFFFF)) for _ in names]
    elif kind == "TIME__":
        vals = [draw(st.floats(0, 86399.999))]
    elif kind == "HETHS":
        vals = [draw(st.floats(0, 359.999)), draw(st.sampled_from("AEMSV"))]
    elif kind == "HEHDT":
        vals = [draw(st.floats(0, 359.999))]
    else:
        vals = [draw(st.floats(-1e5, 1e5)) for _ in names]
    return phins_ascii.make(kind, *vals)


@st.composite
def generic_sentences(draw) -> phins_ascii.PhinsSentence:
    kind = draw(st.text(alphabet="ABCDEFGHIJKLMNOPQRSTUVWXYZ_", min_size=5, max_size=6))
    pixse = draw(st.booleans())
    # a known sentence id is not generic, and "$PIXSE," is the envelope of iXblue's proprietary
    # sentences (``pixse=True``), not a sentence id of its own
    if kind in phins_ascii.SENTENCES or kind == "PIXSE":
        kind = "X" + kind[1:]
    return phins_ascii.PhinsSentence(kind, tuple(draw(st.lists(_ASCII_TEXT, max_size=6))),
                                     {}, pixse)


@st.composite
def digiquartz_lines(draw) -> digiquartz.DigiquartzLine:
    if draw(st.booleans()):
        value = draw(st.floats(-100.0, 20000.0))
        return digiquartz.pressure_line(value, src=draw(st.integers(1, 99)),
                                        digits=draw(st.integers(0, 6)))
    name = draw(st.sampled_from(["UN", "PI", "TI", "SN", "VR", "MD"]))
    val = draw(st.text(alphabet="0123456789.ABCXYZ-", min_size=1, max_size=10))
    return digiquartz.decode_line(b"*0001" + f"{name}={val}".encode() + b"\r\n")


# ---- valid frames from the recordings, for the fuzz tests ---------------------------------
def sample_frames(codec_name: str) -> list[bytes]:
    """Raw valid frames of one codec (from the recordings; Digiquartz from the codec)."""
    if codec_name == "pd0":
        raw = read_data("pd0/adcp_auv_3.pd0") + read_data("pd0/LB180210_3_corrupted.PD0")
        frames, _ = decode_bytes(pd0.Pd0Codec(), raw, keep_raw=True)
    elif codec_name == "phins-stdbin":
        raw = b"".join(read_data(f"phins/log_STDBIN_V{v}.log") for v in (2, 4, 5))
        frames, _ = decode_bytes(phins_stdbin.StdbinCodec(), raw, keep_raw=True)
    elif codec_name == "phins-ascii":
        frames, _ = decode_bytes(phins_ascii.PhinsAsciiCodec(),
                                 read_data("phins/phins_ascii_samples.txt"), keep_raw=True)
    else:
        return [digiquartz.encode_line(digiquartz.pressure_line(v)) for v in
                (14.69595, 18.2, 0.0, 101.325)] + [b"*0001UN=1\r\n"]
    return [r for _, r in frames]


CODECS = {"pd0": pd0.Pd0Codec, "phins-stdbin": phins_stdbin.StdbinCodec,
          "phins-ascii": phins_ascii.PhinsAsciiCodec, "digiquartz": digiquartz.DigiquartzCodec}


@st.composite
def mutated(draw, frame: bytes) -> bytes:
    """A valid frame damaged by a few random edits (flip, delete, insert, cut, repeat)."""
    b = bytearray(frame)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "delete", "insert", "cut", "repeat", "byte"]))
        if not b:
            break
        i = draw(st.integers(0, len(b) - 1))
        if op == "flip":
            b[i] ^= 1 << draw(st.integers(0, 7))
        elif op == "delete":
            del b[i]
        elif op == "insert":
            b.insert(i, draw(st.integers(0, 255)))
        elif op == "cut":
            del b[i:]
        elif op == "repeat":
            j = draw(st.integers(i, min(len(b), i + 16)))
            b[i:i] = b[i:j]
        else:
            b[i] = draw(st.integers(0, 255))
    return bytes(b)
