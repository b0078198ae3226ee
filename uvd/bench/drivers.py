"""``uvd bench drivers``: decode throughput per codec and pty latency (issue 5 acceptance).

* **Throughput**: a recorded stream (``tests/data``; synthetic frames from the encoders if
  a recording is absent) fed to :class:`~drivers.framing.StreamDecoder` in 4 KiB chunks, as a
  transport does, repeated for ``--duration`` seconds; frames/s is the median over repetitions
  (wall clock), also given per CPU-second of this process and as the best pass, with the load
  average: on a shared machine other processes take the wall clock, not the CPU cost.
  Target: PD0 ≥ 20 000 ensembles/s.
* **Latency**: one frame written to a pseudo-terminal master, timed from the return of the
  write (the last byte written) to the frame returned by ``SerialFrameReader.get`` (decoded,
  stamped, queued); ``--samples`` frames per codec, 2 ms apart. Target: median ≤ 1 ms.
* ``nav_step`` time per call (all three samples fresh, and none).

Figures are printed and written, never asserted.
"""

from __future__ import annotations

import asyncio
import os
import time
import tty
from pathlib import Path

import numpy as np

from drivers import digiquartz, pd0, phins_ascii, phins_stdbin
from drivers.framing import StreamDecoder
from drivers.samples import DepthSample, DvlSample, InsSample
from uvd.bench import Bench, percentiles
from uvd.cliargs import positive_float, positive_int

#: the real recordings of a checkout (tests/data/); an installed package has none: synthetic
#: frames then
DEFAULT_DATA = Path(__file__).resolve().parents[2] / "tests" / "data"


def _add_arguments(p) -> None:
    p.add_argument("--duration", type=positive_float, default=1.0,
                   help="seconds of decoding per codec (default 1)")
    p.add_argument("--samples", type=positive_int, default=300,
                   help="latency samples per codec (default 300)")
    p.add_argument("--data", type=Path, default=DEFAULT_DATA,
                   help="folder of the recordings (default tests/data of the checkout)")


def _streams(data_dir: Path) -> dict[str, tuple[object, bytes, str]]:
    def rec(rel):
        p = data_dir / rel
        return p.read_bytes() if p.is_file() else None

    out = {}
    raw = rec("pd0/RDI_withBT.000")
    if raw is None:
        raw = b"".join(pd0.encode_ensemble(pd0.from_dvl_velocity(np.array([0.1, 0.0, 0.0]),
                                                                 3.0, ensemble_number=k))
                       for k in range(1000))
        src = "synthetic (from_dvl_velocity)"
    else:
        src = "pd0/RDI_withBT.000"
    out["pd0"] = (pd0.Pd0Codec, raw, src)
    raw = rec("phins/log_STDBIN_V3.log")
    src = "phins/log_STDBIN_V3.log × 50"
    if raw is None:
        raw = phins_stdbin.encode_frame(phins_stdbin.from_state((0.0, 0.0, 1.0), np.zeros(3)))
        src = "synthetic (from_state) × 50"
    out["phins-stdbin"] = (phins_stdbin.StdbinCodec, raw * 50, src)
    raw = rec("phins/phins_ascii_samples.txt")
    src = "phins/phins_ascii_samples.txt × 50"
    if raw is None:
        raw = b"".join(phins_ascii.encode_sentence(s)
                       for s in phins_ascii.from_state(0.01, 0.02, 1.0, 3600.0))
        src = "synthetic (from_state) × 50"
    out["phins-ascii"] = (phins_ascii.PhinsAsciiCodec, raw * 50, src)
    lines = b"".join(digiquartz.encode_line(digiquartz.pressure_line(14.69595 + 1e-4 * k))
                     for k in range(2000))
    out["digiquartz"] = (digiquartz.DigiquartzCodec, lines, "synthetic pressure lines")
    return out


def _throughput(codec_cls, raw: bytes, duration: float) -> dict:
    rates, cpu_rates = [], []
    n_frames = 0
    t_end = time.perf_counter() + duration
    while True:
        dec = StreamDecoder(codec_cls())
        t0 = time.perf_counter()
        c0 = time.process_time()
        n = 0
        for i in range(0, len(raw), 4096):
            n += len(dec.feed(raw[i:i + 4096]))
        n += len(dec.finish())
        dt = time.perf_counter() - t0
        dc = time.process_time() - c0
        rates.append(n / dt)
        if dc > 0:
            cpu_rates.append(n / dc)
        n_frames = n
        if time.perf_counter() > t_end and len(rates) >= 3:
            break
    return {"frames_per_s": float(np.median(rates)),
            "frames_per_cpu_s": float(np.median(cpu_rates)) if cpu_rates else None,
            "best_frames_per_s": float(np.max(rates)), "frames_per_pass": n_frames,
            "bytes_per_s": float(np.median(rates)) * len(raw) / max(n_frames, 1),
            "passes": len(rates)}


def _latency_frames() -> dict[str, tuple[object, bytes]]:
    ens = pd0.encode_ensemble(pd0.from_dvl_velocity(np.array([0.3, 0.0, 0.0]), 2.0))
    stb = phins_stdbin.encode_frame(phins_stdbin.from_state((0.01, 0.02, 1.0),
                                                            np.array([0.0, 0.0, 0.1]),
                                                            np.zeros(3)))
    att = phins_ascii.encode_sentence(phins_ascii.make("ATITUD", 1.0, -2.0))
    dq = digiquartz.encode_line(digiquartz.pressure_line(16.0))
    return {"pd0": (pd0.Pd0Codec, ens), "phins-stdbin": (phins_stdbin.StdbinCodec, stb),
            "phins-ascii": (phins_ascii.PhinsAsciiCodec, att),
            "digiquartz": (digiquartz.DigiquartzCodec, dq)}


async def _pty_latency(codec_cls, frame: bytes, samples: int) -> dict:
    from drivers.serial_transport import SerialFrameReader

    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    lat = []
    try:
        reader = SerialFrameReader(os.ttyname(slave), codec_cls(), name="bench")
        async with reader:
            await reader.wait_connected(5.0)
            for _ in range(samples):
                os.write(master, frame)
                t0 = time.perf_counter_ns()
                await reader.get(timeout=2.0)
                lat.append((time.perf_counter_ns() - t0) * 1e-9)
                await asyncio.sleep(0.002)
    finally:
        os.close(master)
        os.close(slave)
    return percentiles(lat)


def _nav_step_times(n: int = 20000) -> dict:
    from uvd.estimation.navigation import NavConfig, nav_init, nav_step

    cfg = NavConfig()
    mem = nav_init(cfg)
    w = np.array([0.01, -0.02, 0.1])
    vb = np.array([0.3, 0.0, 0.05])
    full, empty = [], []
    for k in range(n):
        t = k * 10_000_000
        ins = InsSample(t, 0.01, 0.02, 1.0, w)
        dvl = DvlSample(t, vb, True)
        dep = DepthSample(t, 2.0)
        t0 = time.perf_counter_ns()
        _, mem = nav_step(cfg, mem, t, ins, dvl, dep)
        t1 = time.perf_counter_ns()
        _, mem = nav_step(cfg, mem, t + 5_000_000, None, None, None)
        t2 = time.perf_counter_ns()
        full.append((t1 - t0) * 1e-9)
        empty.append((t2 - t1) * 1e-9)
    return {"all_samples": percentiles(full), "no_samples": percentiles(empty)}


def run(args) -> dict:
    duration = float(getattr(args, "duration", 1.0))
    samples = int(getattr(args, "samples", 300))
    data_dir = Path(getattr(args, "data", DEFAULT_DATA))
    throughput = {}
    for name, (codec_cls, raw, src) in _streams(data_dir).items():
        throughput[name] = {**_throughput(codec_cls, raw, duration), "source": src}
    latency = {}
    for name, (codec_cls, frame) in _latency_frames().items():
        latency[name] = {**asyncio.run(_pty_latency(codec_cls, frame, samples)),
                         "frame_bytes": len(frame)}
    figures = {
        "load_average_1min_before": os.getloadavg()[0],
        "throughput": throughput,
        "pty_latency_us": latency,
        "nav_step_us": _nav_step_times(max(1000, int(20000 * min(duration, 1.0)))),
        "load_average_1min_after": os.getloadavg()[0],
        "targets": {"pd0_frames_per_s_min": 20000, "pty_latency_p50_us_max": 1000},
        "met": {"pd0_throughput": throughput["pd0"]["frames_per_s"] >= 20000,
                "pty_latency_p50": all(v["p50"] <= 1000 for v in latency.values())},
    }
    return figures


BENCH = Bench(name="drivers",
              summary="decode throughput per codec, last byte → frame latency over a pty, "
                      "nav_step time",
              run=run, add_arguments=_add_arguments)
