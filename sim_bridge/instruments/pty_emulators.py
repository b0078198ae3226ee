"""INS, DVL and depth-sensor emulators writing real wire frames onto pseudo-terminals.

The daemon cannot tell them from hardware: each instrument is a pty pair whose slave side is
reachable at a stable symlink path (``/tmp/uvd-sim/ins`` → ``/dev/pts/7``), and the frames
are produced by the same codecs the daemon decodes with — PHINS STDBIN (or PHINS standard
ASCII), RDI PD0 bottom track, Digiquartz ``*0001<pressure>`` lines. Values come from
:class:`sim_bridge.instruments.models.Instruments` (thesis Table A.1 rates and noise, seeded
``numpy.random.Generator``) sampling the plant's true state.

Start::

    emu = InstrumentEmulators(state, {"ins": "/tmp/uvd-sim/ins", "dvl": "/tmp/uvd-sim/dvl",
                                      "depth": "/tmp/uvd-sim/depth"},
                              Instruments(InstrumentConfig(), np.random.default_rng(seed)))
    async with emu:          # creates the ptys and symlinks, writes frames until exit
        ...                  # the daemon opens the symlink paths as serial ports

``state(t_ns) -> (H, v)`` returns the plant's true pose (4×4, body → world NED) and body
velocity [ν; ω] at ``t_ns`` nanoseconds since the emulator started. :meth:`unplug` and
:meth:`replug` emulate a cable pulled and put back (the pty disappears, a new one appears at
the same symlink path).

The depth sensor answers host commands like a Digiquartz: ``P3`` one sample, ``P4``
continuous samples at the model's rate (the power-up mode here, ``depth_continuous``), ``UN``
the unit; any other command stops continuous output.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivers import digiquartz, pd0, phins_ascii, phins_stdbin
from drivers.framing import StreamDecoder
from drivers.pty import PtyPort
from sim_bridge.instruments.models import Instruments

StateFn = Callable[[int], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class EmulatorConfig:
    """Wire-level settings of the emulated instruments (rates and noise: the model's config).

    Attributes
    ----------
    ins_protocol : {"stdbin", "ascii"}
        PHINS output protocol.
    stdbin_version : int
        STDBIN protocol version 2–5.
    dvl_coord : {"ship", "instrument"}
        PD0 coordinate frame of the bottom track.
    depth : DepthConverter
        Unit and water of the Digiquartz (pressure from the model's depth).
    depth_continuous : bool
        Start in P4 (continuous) mode.
    depth_digits : int
        Decimals of the pressure reply.
    tick_s : float
        Emulator loop period; samples fall due on the model's own schedule.
    """

    ins_protocol: str = "stdbin"
    stdbin_version: int = 3
    dvl_coord: str = "ship"
    depth: digiquartz.DepthConverter = field(default_factory=digiquartz.DepthConverter)
    depth_continuous: bool = True
    depth_digits: int = 6
    tick_s: float = 0.001

    def __post_init__(self):
        if self.ins_protocol not in ("stdbin", "ascii"):
            raise ValueError(f"ins_protocol must be 'stdbin' or 'ascii', not "
                             f"{self.ins_protocol!r}")
        if self.stdbin_version not in phins_stdbin.HEADER_SIZE:
            raise ValueError(f"stdbin_version must be 2–5, not {self.stdbin_version!r}")
        if not 0 < self.tick_s <= 0.05:
            raise ValueError("tick_s must be in (0, 0.05] s")


class InstrumentEmulators:
    """INS, DVL and depth sensor on ptys, driven by the plant's true state.

    Parameters
    ----------
    state : callable
        ``state(t_ns) -> (H, v)``: true pose (4, 4) and body velocity (6,) at ``t_ns`` ns
        since start.
    links : dict
        Symlink path per instrument, keys among ``"ins"``, ``"dvl"``, ``"depth"``.
    instruments : Instruments
        The instrument model (rates, noise, seeded generator).
    config : EmulatorConfig
    clock : callable
        Monotonic ns clock (injected).
    """

    def __init__(self, state: StateFn, links: dict[str, str | Path], instruments: Instruments,
                 config: EmulatorConfig | None = None,
                 clock: Callable[[], int] = time.monotonic_ns):
        unknown = set(links) - {"ins", "dvl", "depth"}
        if unknown:
            raise ValueError(f"unknown instrument(s) {sorted(unknown)}; use ins, dvl, depth")
        self.state = state
        self.instruments = instruments
        self.config = config or EmulatorConfig()
        self.clock = clock
        self.ports = {name: PtyPort(path) for name, path in links.items()}
        self.depth_continuous = self.config.depth_continuous
        self._depth_once = False
        self._cmd = StreamDecoder(digiquartz.DigiquartzCodec())
        self.t0_ns: int | None = None  # monotonic time of t = 0 (set by start)
        self._task: asyncio.Task | None = None
        self._stop = False
        self._counter = 0
        self._ens = 0
        self.last_truth: tuple[int, np.ndarray, np.ndarray] | None = None

    # ---- lifecycle -------------------------------------------------------------------------
    def open(self) -> None:
        """Create every pty and symlink (done by :meth:`start` too)."""
        for p in self.ports.values():
            p.open()

    def close(self) -> None:
        for p in self.ports.values():
            p.close()

    def unplug(self, name: str) -> None:
        """Pull the cable of one instrument: its pty and symlink disappear."""
        self.ports[name].close()

    def replug(self, name: str) -> None:
        """Plug it back: a new pty at the same symlink path."""
        self.ports[name].open()

    def start(self, t0_ns: int | None = None) -> asyncio.Task | None:
        """Open the ports and write frames on the emulator's own ``tick_s`` loop; or, given
        ``t0_ns`` (monotonic), let the owner call :meth:`step` with times counted from it
        (sim-bridge, after each plant step: the instruments then sample the state of that
        step's instant, on the plant's grid as in lockstep simulation)."""
        self.open()
        self._stop = False
        if t0_ns is not None:
            self.t0_ns = t0_ns
            return None
        if self._task is None or self._task.done():
            self._task = asyncio.get_running_loop().create_task(self.run(), name="instruments")
        return self._task

    async def stop(self) -> None:
        self._stop = True
        task = self._task
        if task is not None and not task.done():
            task.cancel()
            await asyncio.wait({task}, timeout=2.0)
        self.close()

    async def __aenter__(self) -> InstrumentEmulators:
        self.start()
        return self

    async def __aexit__(self, *exc) -> None:
        await self.stop()

    async def run(self) -> None:
        """Emit frames until stopped (absolute-deadline loop, ``tick_s`` period)."""
        self.t0_ns = t0 = self.clock()
        tick = int(self.config.tick_s * 1e9)
        k = 0
        while not self._stop:
            self.step(self.clock() - t0)
            k += 1
            delay = (t0 + k * tick - self.clock()) * 1e-9
            if delay < -0.05:  # fell far behind (suspended): do not burst
                k = (self.clock() - t0) // tick + 1
                delay = 0.0
            await asyncio.sleep(max(0.0, delay))

    def set_epoch(self, t_ns: int | None) -> None:
        """The instruments' noise epoch at monotonic ``t_ns`` (None: before it), on the
        emulator's own clock (:meth:`~sim_bridge.instruments.models.Instruments.set_epoch`)."""
        t0 = self.t0_ns if self.t0_ns is not None else t_ns
        self.instruments.set_epoch(None if t_ns is None else t_ns - t0)

    # ---- one emulator step (pure apart from the writes) --------------------------------------
    def step(self, t_ns: int) -> None:
        """Sample the model at ``t_ns`` (since start) and write the frames that fell due."""
        if "depth" in self.ports:
            self._handle_depth_commands()
        H, v = self.state(t_ns)
        ins, dvl, depth = self.instruments.sample(t_ns, H, v)
        self.last_truth = (t_ns, H, v)
        if ins is not None and "ins" in self.ports:
            self._write_ins(t_ns, ins, v)
        if dvl is not None and "dvl" in self.ports:
            self._ens += 1
            ens = pd0.from_dvl_velocity(dvl.velocity_body, dvl.altitude_m,
                                        ensemble_number=self._ens, coord=self.config.dvl_coord,
                                        lock=dvl.bottom_lock)
            self.ports["dvl"].write(pd0.encode_ensemble(ens))
        if depth is not None and "depth" in self.ports and (self.depth_continuous
                                                            or self._depth_once):
            self._depth_once = False
            conv = self.config.depth
            value = conv.pressure_from_depth_pa(depth.depth_m) / digiquartz.UNIT_PA[conv.unit]
            line = digiquartz.pressure_line(value, digits=self.config.depth_digits)
            self.ports["depth"].write(digiquartz.encode_line(line))

    def _write_ins(self, t_ns: int, ins, v: np.ndarray) -> None:
        port = self.ports["ins"]
        if self.config.ins_protocol == "stdbin":
            self._counter += 1
            fr = phins_stdbin.from_state((ins.roll, ins.pitch, ins.heading), ins.omega_body,
                                         v_body=np.asarray(v[:3]),
                                         validity_time_100us=(t_ns // 100_000) & 0xFFFFFFFF,
                                         counter=self._counter,
                                         version=self.config.stdbin_version)
            port.write(phins_stdbin.encode_frame(fr))
        else:
            burst = b"".join(phins_ascii.encode_sentence(s) for s in phins_ascii.from_state(
                ins.roll, ins.pitch, ins.heading, t_utc_s=t_ns * 1e-9))
            port.write(burst)

    def _handle_depth_commands(self) -> None:
        port = self.ports["depth"]
        data = port.read()
        if not data:
            return
        for line in self._cmd.feed(data):
            if line.kind != "command":
                continue
            name = line.name
            if name == "P3":
                self._depth_once = True
                self.depth_continuous = False
            elif name == "P4":
                self.depth_continuous = True
            elif name == "UN" and "=" not in line.text:
                port.write(b"*0001UN=%d\r\n" % self.config.depth.unit)
            else:
                self.depth_continuous = False


def main(argv: list[str] | None = None) -> int:
    """``python -m sim_bridge.instruments.pty_emulators DIR``: a still vehicle at 2 m depth."""
    import argparse

    from sim_bridge.instruments.models import InstrumentConfig
    from uvd.cliargs import positive_float

    ap = argparse.ArgumentParser(description=main.__doc__)
    ap.add_argument("dir", type=Path, help="folder for the ins, dvl, depth symlinks")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ins-protocol", choices=["stdbin", "ascii"], default="stdbin")
    ap.add_argument("--seconds", type=positive_float, default=None,
                    help="stop after this long (default: run until interrupted)")
    args = ap.parse_args(argv)
    H = np.eye(4)
    H[2, 3] = 2.0
    v = np.zeros(6)
    emu = InstrumentEmulators(lambda t: (H, v), {k: args.dir / k for k in ("ins", "dvl", "depth")},
                              Instruments(InstrumentConfig(), np.random.default_rng(args.seed)),
                              EmulatorConfig(ins_protocol=args.ins_protocol))

    async def go():
        async with emu:
            print(" ".join(f"{k}={p.link}->{p.device}" for k, p in emu.ports.items()), flush=True)
            await asyncio.sleep(1e9 if args.seconds is None else args.seconds)
    try:
        asyncio.run(go())
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
