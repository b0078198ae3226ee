"""Encode → decode round trips of every codec (hypothesis), exact."""

from __future__ import annotations

import math

import numpy as np
from driver_strategies import (
    digiquartz_lines,
    generic_sentences,
    pd0_ensembles,
    phins_sentences,
    stdbin_frames,
)
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers import digiquartz, frames, pd0, phins_ascii, phins_stdbin
from drivers.framing import StreamDecoder, decode_bytes

RT = settings(max_examples=200, deadline=None)


@RT
@given(pd0_ensembles())
def test_pd0_roundtrip(ens):
    raw = pd0.encode_ensemble(ens)
    back = pd0.decode_ensemble(raw)
    assert back == ens
    assert pd0.encode_ensemble(back) == raw
    frames, dec = decode_bytes(pd0.Pd0Codec(), raw + raw)
    assert frames == [ens, ens] and dec.counters.bytes_dropped == 0


@RT
@given(stdbin_frames())
def test_stdbin_roundtrip(fr):
    raw = phins_stdbin.encode_frame(fr)
    back = phins_stdbin.decode_frame(raw)
    assert back.blocks == fr.blocks
    assert (back.version, back.validity_time_100us, back.counter) == \
        (fr.version, fr.validity_time_100us, fr.counter)
    if fr.nav_size is not None:
        assert back.nav_size == fr.nav_size
    assert phins_stdbin.encode_frame(back) == raw
    frames, dec = decode_bytes(phins_stdbin.StdbinCodec(), raw + raw)
    assert [f.blocks for f in frames] == [fr.blocks, fr.blocks]
    assert dec.counters.bytes_dropped == 0


@RT
@given(st.one_of(phins_sentences(), generic_sentences()))
def test_phins_ascii_roundtrip(s):
    raw = phins_ascii.encode_sentence(s)
    assert phins_ascii.decode_line(raw) == s
    frames, dec = decode_bytes(phins_ascii.PhinsAsciiCodec(), raw + raw)
    assert frames == [s, s] and dec.counters.bytes_dropped == 0


@RT
@given(digiquartz_lines())
def test_digiquartz_roundtrip(line):
    raw = digiquartz.encode_line(line)
    assert digiquartz.decode_line(raw) == line
    frames, dec = decode_bytes(digiquartz.DigiquartzCodec(), raw + raw)
    assert frames == [line, line] and dec.counters.bytes_dropped == 0


# ---- sample-level round trips: our state → wire → our state ---------------------------------
angles = st.floats(-math.pi + 1e-3, math.pi - 1e-3)
small = st.floats(-1.2, 1.2)


@settings(max_examples=200, deadline=None)
@given(small, st.floats(-1.4, 1.4), angles, st.lists(st.floats(-2, 2), min_size=3, max_size=3),
       st.lists(st.floats(-3, 3), min_size=3, max_size=3), st.integers(2, 5))
def test_stdbin_state_roundtrip(roll, pitch, heading, w, v, version):
    fr = phins_stdbin.from_state((roll, pitch, heading), np.array(w), np.array(v),
                                 version=version)
    back = phins_stdbin.decode_frame(phins_stdbin.encode_frame(fr))
    s = phins_stdbin.to_ins_sample(back, 7)
    assert s.valid and s.rates_valid
    tol = 1e-6  # float32 degrees on the wire
    assert abs(math.remainder(s.heading - heading, 2 * math.pi)) < tol
    assert abs(s.roll - roll) < tol and abs(s.pitch - pitch) < tol
    np.testing.assert_allclose(s.omega_body, w, atol=1e-6)
    np.testing.assert_allclose(phins_stdbin.body_velocity(back), v, atol=1e-6)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-5, 5), min_size=3, max_size=3), st.floats(0.2, 100.0),
       st.sampled_from(["ship", "instrument"]), st.sampled_from([20, 30]))
def test_pd0_velocity_roundtrip(v, altitude, coord, angle):
    ens = pd0.from_dvl_velocity(np.array(v), altitude, coord=coord, beam_angle_deg=angle)
    s = pd0.to_dvl_sample(pd0.decode_ensemble(pd0.encode_ensemble(ens)), 5)
    assert s.bottom_lock and s.good_beams == 4
    np.testing.assert_allclose(s.velocity_body, v, atol=0.5e-3 + 1e-12)  # 1 mm/s wire
    assert abs(s.altitude_m - altitude) < 0.01


@settings(max_examples=200, deadline=None)
@given(small, st.floats(-1.4, 1.4), angles)
def test_phins_ascii_state_roundtrip(roll, pitch, heading):
    asm = phins_ascii.AsciiInsAssembler()
    out = None
    for k, s in enumerate(phins_ascii.from_state(roll, pitch, heading)):
        s2 = phins_ascii.decode_line(phins_ascii.encode_sentence(s))
        out = asm.push(k * 1000, s2) or out
    assert out is not None and out.valid and not out.rates_valid
    tol = math.radians(0.0005) + 1e-12  # 3 decimals of a degree on the wire
    assert abs(math.remainder(out.heading - heading, 2 * math.pi)) <= tol
    assert abs(out.roll - roll) <= tol and abs(out.pitch - pitch) <= tol


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 10.0), st.sampled_from(sorted(digiquartz.UNIT_PA)),
       st.sampled_from(["fresh", "sea"]))
def test_digiquartz_depth_roundtrip(depth, unit, water):
    conv = digiquartz.DepthConverter(unit=unit, water=water)
    value = conv.pressure_from_depth_pa(depth) / digiquartz.UNIT_PA[unit]
    line = digiquartz.pressure_line(value, digits=8)
    s = conv.to_sample(digiquartz.decode_line(digiquartz.encode_line(line)), 1)
    assert abs(s.depth_m - depth) < 1e-4


def test_stream_decoder_partial_frames_across_feeds():
    """Any split of a stream into chunks gives the same frames as one feed."""
    raw = b"".join(phins_stdbin.encode_frame(phins_stdbin.from_state(
        (0.1 * k, 0.0, 0.2), np.zeros(3), counter=k)) for k in range(5))
    whole, _ = decode_bytes(phins_stdbin.StdbinCodec(), raw)
    for chunk in (1, 2, 7, 33, 1000):
        dec = StreamDecoder(phins_stdbin.StdbinCodec())
        got = []
        for i in range(0, len(raw), chunk):
            got += dec.feed(raw[i:i + chunk])
        assert [f.counter for f in got] == [f.counter for f in whole] == list(range(5))
        assert dec.buffered == 0


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=3000))
def test_byte_sum_is_the_plain_sum(data):
    from drivers._layout import byte_sum

    assert byte_sum(data) == sum(data)


def _beam_ensemble(v_vehicle_body, bad_beam=None, angle=30):
    """A beam-coordinate ensemble for a vehicle velocity (inverse RDI Janus geometry)."""
    ens = pd0.from_dvl_velocity(np.zeros(3), 5.0, beam_angle_deg=angle)
    # bottom motion in RDI instrument axes (X stbd, Y fwd, Z up) = −vehicle motion
    x, y, z = (-v_vehicle_body[1], -v_vehicle_body[0], v_vehicle_body[2])
    th = math.radians(angle)
    beams = [x * math.sin(th) + z * math.cos(th), -x * math.sin(th) + z * math.cos(th),
             -y * math.sin(th) + z * math.cos(th), y * math.sin(th) + z * math.cos(th)]
    vel = [round(b * 1000) for b in beams]
    rng = list(ens.bottom_track["range_cm"])
    if bad_beam is not None:
        vel[bad_beam] = pd0.BAD_VELOCITY
        rng[bad_beam] = 0
    fixed = {**ens.fixed, "coord_transform": 0b00000}  # EX00000: beam coordinates
    bt = {**ens.bottom_track, "velocity_mm_s": tuple(vel), "range_cm": tuple(rng)}
    return pd0.decode_ensemble(pd0.encode_ensemble(
        pd0.Pd0Ensemble(fixed, ens.variable, bt, {}, {}, ens.order)))


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-2, 2), min_size=3, max_size=3), st.sampled_from([None, 0, 1, 2, 3]))
def test_pd0_beam_coordinates_to_body_velocity(v, bad):
    ens = _beam_ensemble(np.array(v), bad)
    assert ens.coord_frame == "beam"
    s = pd0.to_dvl_sample(ens, 0)
    assert s.bottom_lock and s.good_beams == (4 if bad is None else 3)
    np.testing.assert_allclose(s.velocity_body, v, atol=3e-3)  # 1 mm/s per beam, ×1/sin θ


def test_pd0_two_bad_beams_is_no_lock():
    ens = _beam_ensemble(np.array([0.5, 0.0, 0.0]), 0)
    bt = dict(ens.bottom_track)
    bt["velocity_mm_s"] = (pd0.BAD_VELOCITY, pd0.BAD_VELOCITY) + bt["velocity_mm_s"][2:]
    bt["range_cm"] = (0, 0) + bt["range_cm"][2:]
    s = pd0.to_dvl_sample(pd0.Pd0Ensemble(ens.fixed, ens.variable, bt, {}, {}, ens.order), 0)
    assert not s.bottom_lock and s.good_beams == 2 and np.all(np.isnan(s.velocity_body))


def test_pd0_earth_coordinates_need_the_attitude():
    from uvd.geometry import euler_to_R

    v_body = np.array([0.4, -0.1, 0.05])
    R = euler_to_R(0.05, -0.1, 2.0)
    east, north, up = frames.ned_to_enu(-(R @ v_body))  # the bottom's motion, ENU
    ens = pd0.from_dvl_velocity(np.zeros(3), 5.0)
    fixed = {**ens.fixed, "coord_transform": 0b11111}
    bt = {**ens.bottom_track, "velocity_mm_s": (round(east * 1e3), round(north * 1e3),
                                                round(up * 1e3), 0)}
    ens = pd0.Pd0Ensemble(fixed, ens.variable, bt, {}, {}, ens.order)
    assert ens.coord_frame == "earth"
    assert not pd0.to_dvl_sample(ens, 0).bottom_lock  # no attitude: cannot rotate to body
    s = pd0.to_dvl_sample(ens, 0, R_body_to_world=R)
    assert s.bottom_lock
    np.testing.assert_allclose(s.velocity_body, v_body, atol=2e-3)
