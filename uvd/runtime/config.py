"""The daemon's configuration: one TOML file validated at start into frozen dataclasses.

:func:`load_config` parses the file and validates it against the schema of :class:`Config`
(:mod:`uvd.runtime.schema`); any problem raises :class:`ConfigValidationError`, whose message
has one line per problem naming the file, the dotted key and the reason::

    config/bad.toml: control.kp: -5.0 is out of range (must be ≥ 0 and ≤ 100000)
    config/bad.toml: sensors.ins.port: missing required key (string, device path …)

``uvd check-config FILE`` does the same without starting anything, and
``uvd check-config --doc-out docs/config.md`` writes the reference generated from the schema
(:func:`render_config_doc`), so every key, unit and default is documented by construction.

Sections and where their dataclass lives:

===================  =========================================================================
``[vehicle]``        :class:`VehicleSection` — built-in vehicle or vehicle file
``[loop]``           :class:`uvd.runtime.loop.LoopSettings`
``[control]``        :class:`ControlSection`
``[failsafe]``       :class:`uvd.runtime.failsafe.Thresholds`
``[navigation]``     :class:`NavigationSection` — the dead-reckoning start fix
``[estimation]``     :class:`EstimationSection` — online identification (AID)
``[sensors.*]``      :class:`InsSection`, :class:`DvlSection`, :class:`DepthSection`; the depth
                     conversion is the driver's own :class:`drivers.digiquartz.DepthConverter`;
                     ``[sensors.leak]`` is :class:`uvd.runtime.leak.LeakSection`
``[can]``            :class:`CanSection` (bus keys; ``[can.amplifiers]``, ``[can.depth]``,
                     ``[can.log]``), converted into the CAN driver's plain
                     :class:`drivers.can.config.CanConfig`
``[telemetry]``      :class:`TelemetrySection`
``[mavlink]``        :class:`MavlinkSection` — the ground-station link (docs/mavlink.md)
``[daemon]``         :class:`DaemonSection` — start/stop timeouts, the shutdown sequence
``[faults]``         :class:`uvd.runtime.fdc_source.FaultsSection` — sources of thruster
                     effectiveness η and their rules (``[faults.fdc]``: uvd-fdc over Zenoh)
===================  =========================================================================

**Plugging in a subsystem's own configuration.** Any frozen dataclass can be a section: put
it in a :class:`Config` (or nested section) field with :func:`~uvd.runtime.schema.section`.
Fields declared with :func:`~uvd.runtime.schema.setting` carry unit, range, doc and the
reload flag; plain fields are validated by type and documented from the class's numpydoc
``Attributes``/``Parameters``. A plain dataclass of a driver (drivers never import uvd) can
instead be declared here by a section of settings that converts into it
(:data:`uvd.runtime.schema.DECLARED_BY`; how ``[can]`` becomes ``CanConfig``).
"""

from __future__ import annotations

import dataclasses
import ipaddress
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from drivers.can.config import (
    DEFAULT_AMPLIFIER_EDS,
    DEFAULT_PRESSURE_EDS,
    DEFAULT_UDP_GROUP,
    DEFAULT_UDP_PORT,
    LOG_SUFFIXES,
    AmplifierConfig,
    CanBusConfig,
    CanConfig,
    CanLogConfig,
)
from drivers.can.config import DepthConfig as CanDepthConfig
from drivers.digiquartz import DepthConverter
from uvd.errors import ConfigError
from uvd.io.toml import TomlFileError, other_kind, read_toml, refused_name
from uvd.runtime import schema
from uvd.runtime.failsafe import Thresholds
from uvd.runtime.fdc_source import FaultsSection
from uvd.runtime.leak import LeakSection
from uvd.runtime.loop import LoopSettings
from uvd.runtime.schema import PerAxis, section, setting
from uvd.shipped import CONFIG_DIR, DEFAULT_CONFIG, config_path, shipped_configs

__all__ = ["Config", "ConfigValidationError", "load_config", "parse_config",
           "render_config_doc", "DEFAULT_CONFIG", "CONFIG_DIR", "shipped_configs",
           "config_path", "VehicleSection", "ControlSection",
           "InsSection", "DvlSection", "DepthSection", "SensorsSection", "TelemetrySection",
           "JsonlSection", "DaemonSection", "NavigationSection", "EstimationSection",
           "CanSection", "CanAmplifiersSection", "CanDepthSection", "CanLogSection"]

# The shipped configurations and the embedded default: package data (uvd.shipped)

BAUD_RATES = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)
_URL = re.compile(r"^(udp|tcp)://(?P<host>[^:/]+|\[[0-9a-fA-F:]+\]):(?P<port>\d{1,5})$")
_PYSERIAL_URL = re.compile(r"^(socket|rfc2217|loop|spy|alt|hwgrep)://")


class ConfigValidationError(ConfigError):
    """A configuration file failed validation.

    Attributes
    ----------
    source : str
        The file (or ``<string>``).
    errors : list of (str, str)
        ``(dotted.key, reason)`` for every problem.
    """

    def __init__(self, source: str, errors: list[tuple[str, str]]) -> None:
        self.source = source
        self.errors = list(errors)
        lines = [f"{source}: {k}: {r}" if k else f"{source}: {r}" for k, r in self.errors]
        super().__init__("\n".join(lines))


# ------------------------------------------------------------------------------ sections

@dataclass(frozen=True)
class VehicleSection:
    """The vehicle model (``[vehicle]``)."""

    name: str = setting("jhu-rov", doc="built-in vehicle (jhu-rov, jhu-rov-coupled, "
                                       "bluerov2-heavy) or a vehicle TOML file, relative to "
                                       "this config file")

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        from uvd.io.vehicle import builtin_vehicles
        if self.name in builtin_vehicles():
            return []
        p = Path(self.name)
        if p.suffix != ".toml":
            return [("name", f"{self.name!r} is neither a built-in vehicle "
                             f"({', '.join(builtin_vehicles())}) nor a .toml file")]
        full = p if p.is_absolute() else ctx.base_dir / p
        if why := refused_name(full):
            return [("name", f"vehicle file {self.name!r:.80}: {why}")]
        if not full.is_file():
            return [("name", f"vehicle file {self.name!r} not found (relative paths are taken "
                             f"from {ctx.base_dir})")]
        return []


@dataclass(frozen=True)
class ControlSection:
    """The controller (``[control]``); gains apply to every controller's PD part (5.11)."""

    controller: Literal["pdc", "ambc", "two-step-ambc"] = setting(
        "pdc", doc="PD control (5.11), adaptive model-based control, or its two-step form "
                   "(§5.3.5)")
    kp: PerAxis = setting(300.0, unit="N/rad, N m/rad", min=0.0, max=100000.0, reload=True,
                          doc="proportional gain k_p on Δψ: one for every DOF or six (surge, "
                              "sway, heave, roll, pitch, yaw) (thesis §5.3.5.1: 300)")
    kd: PerAxis = setting(100.0, unit="N s/m, N m s/rad", min=0.0, max=100000.0, reload=True,
                          doc="derivative gain k_d on Δv: one or six, as kp (thesis "
                              "§5.3.5.1: 100)")
    gamma_m: PerAxis = setting(1000.0, min=0.0, max=1e9, reload=True,
                               doc="AMBC adaptation gain γ_m of the masses m₁…m₆ (K_θ of "
                                   "(5.28)): one or six, as kp; model = \"full\" takes one "
                                   "(thesis §5.3.2: 1000)")
    gamma_d: PerAxis = setting(5000.0, min=0.0, max=1e9, reload=True,
                               doc="AMBC adaptation gain γ_d of the drags d₁…d₆: one or six, "
                                   "as gamma_m (thesis §5.3.2: 5000)")
    mass_floor: PerAxis = setting(
        10.0, unit="kg, kg m²", gt=0.0, max=1e6, reload=True,
        doc="robust adaptation: the smallest m̂ᵢ (decoupled) or eigenvalue of M̂ (full: the "
            "smallest of six) the projection allows; one or six, as kp — below the vehicle's "
            "own masses (a BlueROV2's rotational ones are ~0.4 kg m²)")
    gamma_g: float = setting(0.5, min=0.0, max=1e9, reload=True,
                             doc="AMBC adaptation gain γ_g of g (thesis §5.3.2: 0.5)")
    gamma_b: tuple[float, float, float] = setting(
        (0.5, 0.5, 10.0), min=0.0, max=1e9, reload=True,
        doc="AMBC adaptation gains γ_b1, γ_b2, γ_b3 of b (thesis §5.3.2: 0.5, 0.5, 10)")
    robust_adaptation: bool = setting(
        True, doc="robust (projection/σ) modification of the AMBC parameter update law")
    reference: Literal["hold", "reftraj1", "reftraj2"] = setting(
        "hold", doc="what the armed vehicle tracks: hold the pose it had when armed, or "
                    "RefTraj1/RefTraj2 of Table 5.1 (about the start pose's centre, time "
                    "counted from arming)")
    model: Literal["decoupled", "full"] = setting(
        "decoupled", doc="AMBC parameter model: the 16-parameter decoupled view (§5.3.1) or "
                         "the full θ_UV ∈ R²⁴¹ (2.48)")
    eps: float = setting(1.0, min=0.0, max=100.0,
                         doc="ε of the AMBC update law (5.28) (the thesis does not report it; "
                             "docs/experiments.md)")
    theta0: Literal["zero", "vehicle-gb", "vehicle"] = setting(
        "zero", doc="initial θ̂ of AMBC: zero (§5.3.5 step 1), the vehicle file's g and b with "
                    "M and D zero (the start of §5.3.5 step 2), or every vehicle-file value")
    step1_duration_s: float = setting(
        5400.0, unit="s", min=0.0, max=1e6,
        doc="two-step AMBC: length of step 1 (g, b on the quasi-static trajectory); 0 starts "
            "in step 2 with g, b from theta0")
    lag_compensation: bool = setting(
        False, doc="propeller-lag compensation: send each thruster the lead set-point that "
                   "brings its propeller to the allocated thrust within one cycle, from the "
                   "amplifiers' measured speed and the vehicle file's time_constant_s "
                   "(uvd.control.allocation.lag_compensate); cycles without finite speeds use "
                   "plain allocation")
    dof_priority: tuple[str, ...] = setting(
        ("heave", "roll", "pitch", "yaw", "surge", "sway"),
        doc="the six DOFs, highest priority first: when the thrusters' effectiveness (a weak "
            "or dead thruster) no longer reaches every DOF, allocation keeps these in order "
            "and gives up the last ones, which the controller then neither commands nor "
            "adapts on (uvd.control.allocation.accommodate); depth and attitude first by "
            "default. Surge or sway given up gives up horizontal position too: the "
            "controller acts on neither horizontal translation, the vehicle keeps depth and "
            "attitude and drifts (uvd.control.given_up). With a thruster's "
            "effectiveness set, a command beyond a thruster's limit is resolved in this order "
            "too: each DOF in turn gets the thrust the ones before it left "
            "(uvd.control.allocation.allocate_prioritised)")

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        from uvd.control.allocation import dof_priority_indices
        try:
            dof_priority_indices(self.dof_priority)
        except ValueError as exc:
            return [("dof_priority", str(exc))]
        if self.model == "full":
            return [(k, f"six values need model = \"decoupled\" (the full model's {what} "
                        f"are not per DOF); give one number")
                    for k, what in (("gamma_m", "21 mass entries"), ("gamma_d", "216 drag entries"))
                    if isinstance(getattr(self, k), tuple)]
        return []



@dataclass(frozen=True)
class NavigationSection:
    """Dead reckoning (``[navigation]``)."""

    initial_north_m: float = setting(0.0, unit="m", min=-1e6, max=1e6,
                                     doc="north of the dead-reckoned position at start (the "
                                         "fix the run starts from)")
    initial_east_m: float = setting(0.0, unit="m", min=-1e6, max=1e6,
                                    doc="east of the dead-reckoned position at start")
    propagate_ins: bool = setting(
        True, doc="carry the INS attitude and rate from the sample's time to the cycle's "
                  "with the measured rate and its slope (the INS is not synchronised with the "
                  "loop: its sample is up to one period old); never with rates derived from "
                  "attitude (uvd.estimation.navigation)")


@dataclass(frozen=True)
class EstimationSection:
    """Online identification (``[estimation]``), running whoever drives the vehicle."""

    aid: bool = setting(False, doc="run 6-DOF adaptive identification (Theorem 4.3.1) every "
                                   "cycle, armed or not")
    initial_params: str = setting(
        "", doc="θ̂(0) of AID: a [parameters] TOML (e.g. the save_path of an earlier run, "
                "to go on from its estimate; relative to this config file); empty = INITP of "
                "§4.6 (Tables 4.6-4.7). Its M must be positive definite")
    gains: tuple[float, float, float, float, float] = setting(
        (10.0, 5000.0, 20000.0, 2000.0, 2000.0),
        doc="AID gains [a, γ₁, γ₂, γ₃, γ₄] of Theorem 4.3.1, each > 0: a (1/s) pulls v̂ "
            "toward v (4.23), under 2 × [loop] rate_hz (its Euler step diverges at a·dt ≥ 2); "
            "γ₁, γ₂, γ₃, γ₄ scale the adaptation rates of M̂, D̂ᵢ, ĝ, b̂ "
            "(4.24)-(4.27) (larger = faster); default §4.6's, chosen for the JHU ROV: with "
            "scale_to_vehicle each DOF's γ's are multiplied by its mass over the JHU ROV's")
    scale_to_vehicle: bool = setting(
        True, doc="scale AID to the vehicle, per DOF: DOF j's γ's by m_j over the JHU ROV's "
                  "m_j (times gain_factors), INITP (when no initial_params) entry by entry by "
                  "the vehicle file's M, D, b₃ over the JHU ROV's "
                  "(uvd.estimation.aid.scaled_aid_gains, scaled_initp; §4.6's on the JHU ROV). "
                  "Off: §4.6's gains and INITP as they are, whatever the vehicle")
    gain_factors: tuple[float, float] = setting(
        (1.0, 1.0), min=1e-6, max=1e6,
        doc="with scale_to_vehicle: [translation, rotation] multipliers of the per-DOF gain "
            "scales — the thesis's 22-35 min runs against a short one; `uvd tune --aid-sweep` "
            "suggests them from a logarithmic sweep in simulation (§4.5's rule)")
    decoupled_gain_scale: tuple[float, ...] = setting(
        (), gt=0,
        doc="16 multipliers of the gains of the decoupled parameters m1..m6, d1..d6, g, "
            "b1, b2, b3 (θ_UV's M and D_i diagonals, g, b), each from its excitation in a "
            "simulation of this configuration so that each adapts at one rate "
            "(uvd.estimation.aid.excitation_gain_scale); `uvd tune --aid-sweep` prints "
            "them. Empty = ones (not a MAVLink parameter)")
    publish_every_s: float = setting(
        1.0, unit="s", min=0.01, max=3600.0, reload=True,
        doc="how often the estimate goes to the telemetry sinks as an \"estimate\" record "
            "(θ̂ ∈ R²⁴¹ in the order of (2.48), M̂'s extreme eigenvalues, frozen and why)")
    save_path: str = setting(
        "", doc="write the latest θ̂ to this [parameters] TOML (loadable by initial_params, "
                "uvd xval --params, uvd identify --init) every save_every_s and at shutdown, "
                "atomically; relative to the working directory (under systemd "
                "$STATE_DIRECTORY); empty = not saved")
    save_every_s: float = setting(60.0, unit="s", min=1.0, max=86400.0,
                                  doc="how often save_path is rewritten while running")
    resume: bool = setting(
        False, doc="go on from the last run: AID starts from save_path's file when it exists "
                   "(checked like initial_params), else from initial_params / INITP (the first "
                   "run); needs save_path")

    def initial_params_path(self, base_dir: Path) -> Path | None:
        """``initial_params`` resolved against the config file's folder (None: INITP)."""
        if not self.initial_params:
            return None
        p = Path(self.initial_params)
        return p if p.is_absolute() else base_dir / p

    def resume_path(self) -> Path | None:
        """``save_path`` if ``resume`` and the file is there (resolved against the working
        directory, where the daemon writes it), else None."""
        if self.resume and self.save_path and not refused_name(self.save_path) \
                and Path(self.save_path).is_file():  # a refused name: _check says why
            return Path(self.save_path).absolute()
        return None

    def start_path(self, base_dir: Path) -> Path | None:
        """The parameters file θ̂(0) of AID comes from: :meth:`resume_path`, else
        :meth:`initial_params_path` (None: INITP)."""
        return self.resume_path() or self.initial_params_path(base_dir)

    def aid_params(self, vehicle=None):
        """The :class:`uvd.estimation.aid.AID6Params` of these settings (gains scaled to
        ``vehicle`` with ``scale_to_vehicle``)."""
        import numpy as np

        from uvd.estimation.aid import AID6Gains, AID6Params, scaled_aid_gains
        gains = AID6Gains(*self.gains)
        if vehicle is not None and self.scale_to_vehicle:
            gains = scaled_aid_gains(np.diag(vehicle.params.M), base=gains,
                                     factors=self.gain_factors)
        if self.decoupled_gain_scale:
            from dataclasses import replace

            from uvd.estimation.aid import entry_scale_of
            gains = replace(gains, entry_scale=entry_scale_of(self.decoupled_gain_scale))
        return AID6Params(gains=gains)

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        n = len(self.decoupled_gain_scale)
        if n not in (0, 16):
            return [("decoupled_gain_scale", f"16 numbers (m1..m6, d1..d6, g, b1, b2, b3) or "
                                             f"none, got {n}")]
        try:
            self.aid_params()
        except ValueError as exc:
            return [("gains", str(exc))]
        if self.resume and not self.save_path:
            return [("resume", "needs save_path: the file a run leaves and the next one "
                               "starts from")]
        errors = []
        if why := refused_name(self.save_path or "."):
            errors.append(("save_path", f"{self.save_path!r:.80}: {why}"))
        for key, p in (("initial_params", self.initial_params_path(ctx.base_dir)),
                       ("save_path", self.resume_path())):
            if p is not None:
                errors += _check_start_params(key, p)
        return errors


def _check_start_params(key: str, p: Path) -> list[tuple[str, str]]:
    """A parameters file AID may start from: readable, M positive definite."""
    from uvd.errors import ParameterError
    from uvd.io.params import params_from_toml
    how = " (resume = true starts AID from it; move it away to start afresh)" \
        if key == "save_path" else ""
    try:
        lam = params_from_toml(p).mass_min_eigenvalue()
    except ParameterError as exc:
        return [(key, f"{exc}{how}")]
    if not lam > 0.0:
        return [(key, f"{p}: M is not positive definite (smallest eigenvalue {lam:.4g}); AID "
                      f"needs M̂(t₀) > 0 (Theorem 4.3.1){how}")]
    return []


def _check_port(port: str | None, key: str = "port") -> list[tuple[str, str]]:
    if port is None:
        return []
    if port.startswith("/") or _PYSERIAL_URL.match(port):
        return []
    m = _URL.match(port)
    if m:
        if not 1 <= int(m.group("port")) <= 65535:
            return [(key, f"{port!r}: network port must be in 1..65535")]
        return []
    return [(key, f"{port!r} is neither an absolute device path (/dev/ttyUSB0, "
                  "/dev/serial/by-id/…) nor udp://host:port / tcp://host:port")]


@dataclass(frozen=True)
class InsSection:
    """The INS (PHINS) port (``[sensors.ins]``)."""

    port: str = setting(doc="device path (/dev/serial/by-id/…, a pty) or udp://host:port / "
                            "tcp://host:port for PHINS over Ethernet")
    format: Literal["phins-stdbin", "phins-ascii"] = setting(
        "phins-stdbin", doc="wire format (phins-ascii carries no rates: they are derived)")
    baud: int = setting(115200, unit="bit/s", choices=BAUD_RATES, doc="serial line speed (8N1)")

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        return _check_port(self.port)


@dataclass(frozen=True)
class DvlSection:
    """The DVL (RDI Workhorse, PD0) port (``[sensors.dvl]``)."""

    port: str = setting(doc="device path or udp://host:port / tcp://host:port")
    format: Literal["pd0"] = setting("pd0", doc="wire format")
    baud: int = setting(115200, unit="bit/s", choices=BAUD_RATES, doc="serial line speed (8N1)")

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        return _check_port(self.port)


@dataclass(frozen=True)
class DepthSection:
    """The depth sensor (``[sensors.depth]``): serial Digiquartz or the CAN transmitter."""

    source: Literal["serial", "can"] = setting(
        "serial", doc="serial Paroscientific Digiquartz, or the CiA 404 transmitter of "
                      "[can.depth]")
    port: str | None = setting(None, doc="device path (required when source = \"serial\")")
    format: Literal["digiquartz"] = setting("digiquartz", doc="wire format")
    baud: int = setting(9600, unit="bit/s", choices=BAUD_RATES, doc="serial line speed (8N1)")
    conversion: DepthConverter = section(
        DepthConverter, doc="pressure → depth (the driver's DepthConverter)")

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        if self.source == "serial" and self.port is None:
            return [("port", "missing required key (needed when source = \"serial\")")]
        return _check_port(self.port)


@dataclass(frozen=True)
class SensorsSection:
    """The navigation sensors."""

    ins: InsSection = section(InsSection)
    dvl: DvlSection = section(DvlSection)
    depth: DepthSection = section(DepthSection)
    leak: LeakSection = section(LeakSection)


@dataclass(frozen=True)
class JsonlSection:
    """A JSON-lines telemetry file (``[telemetry.jsonl]``)."""

    enabled: bool = setting(False, doc="record telemetry as one JSON object per line")
    path: str = setting("uvd-telemetry.jsonl",
                        doc="output file (relative to the working directory; under systemd "
                            "$STATE_DIRECTORY)")
    every_n_cycles: int = setting(1, min=1, max=100000, reload=True,
                                  doc="record one cycle in N")


@dataclass(frozen=True)
class ZenohSection:
    """Live state, estimates and health over Zenoh (``[telemetry.zenoh]``, docs/zenoh.md)."""

    enabled: bool = setting(False, doc="publish under uvd/<key>/… (docs/zenoh.md)")
    key: str = setting("", doc="the <vehicle> of the key space; empty: [vehicle] name "
                               "(a file's stem)")
    mode: str = setting("peer", choices=("peer", "client"),
                        doc="peer (others connect to the listen endpoints) or client (through "
                            "a zenohd router at the connect endpoints)")
    listen: tuple[str, ...] = setting(("tcp/127.0.0.1:7447",),
                                      doc="endpoints to listen on (peer mode)")
    connect: tuple[str, ...] = setting((), doc="endpoints to connect to (a router, peers)")
    multicast_scouting: bool = setting(False, doc="find peers by UDP multicast (off: only "
                                                  "the endpoints above)")
    config_file: str = setting("", doc="a Zenoh JSON5 configuration file (TLS, "
                                       "authentication, access control); replaces the keys "
                                       "above, relative to this config file")
    state_hz: float = setting(20.0, unit="Hz", min=0.0, max=1000.0,
                              doc="uvd/<key>/state rate (0: off)")
    health_hz: float = setting(2.0, unit="Hz", min=0.0, max=1000.0,
                               doc="uvd/<key>/health rate (0: off)")

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        from uvd.zenoh_names import endpoint_problem
        return [(f"{name}[{i}]", f"{e!r} {why}")
                for name in ("listen", "connect")
                for i, e in enumerate(getattr(self, name))
                if (why := endpoint_problem(e))]


@dataclass(frozen=True)
class TelemetrySection:
    """Telemetry fed off the loop (``[telemetry]``)."""

    queue_size: int = setting(1024, min=16, max=1_000_000,
                              doc="records buffered per sink; when full the oldest is dropped "
                                  "and counted (the loop never waits)")
    flush_interval_s: float = setting(0.05, unit="s", gt=0.0, max=10.0,
                                      doc="how often each sink's queue is drained")
    jsonl: JsonlSection = section(JsonlSection)
    zenoh: ZenohSection = section(ZenohSection)


def check_udp_address(addr: str, key: str, *, any_port: bool = False
                      ) -> list[tuple[str, str]]:
    """``[(key, why)]`` if ``addr`` is not ADDRESS:PORT (numeric IP, port 1..65535; 0 too with
    ``any_port``: a port to bind, which the kernel then picks), else []."""
    host, sep, port = addr.rpartition(":")
    lowest = 0 if any_port else 1
    try:
        ok = bool(sep) and lowest <= int(port) < 65536
        ipaddress.ip_address(host.strip("[]"))
    except ValueError:
        ok = False
    return [] if ok else [(key, f"{addr!r} is not ADDRESS:PORT (a numeric IPv4/IPv6 address "
                                f"and a port {lowest}-65535)")]


@dataclass(frozen=True)
class MavlinkSection:
    """The ground-station link (``[mavlink]``, docs/mavlink.md): MAVLink 2 over UDP and
    serial."""

    enabled: bool = setting(False, doc="run the MAVLink link (QGroundControl, MAVProxy)")
    listen: str = setting("127.0.0.1:14551",
                          doc="UDP ADDRESS:PORT the link listens on; ground stations send "
                              "here and get telemetry back at their own address; port 0: one "
                              "the kernel picks (then only the connect stations, which answer "
                              "where the datagrams come from, reach it); empty: none")
    connect: tuple[str, ...] = setting(
        (), doc="UDP ADDRESS:PORT the link also sends to (a station that listens, e.g. "
                "QGroundControl on 127.0.0.1:14550)")
    serial: str = setting("", doc="a serial device to also speak MAVLink on (a telemetry "
                                  "radio, e.g. /dev/ttyUSB0); empty: none")
    serial_baud: int = setting(57600, min=1200, max=4_000_000, doc="its baud rate")
    system_id: int = setting(1, min=1, max=255, doc="the vehicle's MAVLink system id")
    component_id: int = setting(1, min=1, max=255,
                                doc="its component id (1 = MAV_COMP_ID_AUTOPILOT1)")
    gcs_system_ids: tuple[int, ...] = setting(
        (255,), min=1, max=255,
        doc="system ids of the ground stations: only their heartbeats count as the "
            "operator's and only their commands are taken (others are counted and dropped)")
    heartbeat_hz: float = setting(1.0, unit="Hz", gt=0.0, max=50.0,
                                  doc="HEARTBEAT and SYS_STATUS rate")
    state_hz: float = setting(10.0, unit="Hz", min=0.0, max=100.0,
                              doc="ATTITUDE, LOCAL_POSITION_NED, SCALED_PRESSURE, VFR_HUD and "
                                  "the thruster outputs (0: off)")
    estimate_hz: float = setting(1.0, unit="Hz", min=0.0, max=50.0,
                                 doc="NAMED_VALUE_FLOAT of the online estimates (0: off)")
    statustext_hz: float = setting(
        20.0, unit="Hz", gt=0.0, max=250.0,
        doc="STATUSTEXT chunks sent a second at most, after 10 at once: a long text's "
            "chunks (up to 256) are paced, not sent in one burst that a station's socket "
            "or a telemetry radio cannot take (20: 1.4 kB/s, beside the 2.4 kB/s of "
            "telemetry at the defaults within a 57600-baud radio's 5.8 kB/s)")
    station_timeout_s: float = setting(
        10.0, unit="s", gt=0.0, max=3600.0,
        doc="a station that listens (not in connect) gets telemetry while heard within this")
    operator_timeout_s: float = setting(
        5.0, unit="s", min=0.0, max=600.0,
        doc="operator-loss failsafe: no ground-station heartbeat for this long while armed "
            "(after one was heard) triggers operator_action; 0 = off (ArduSub's 5 s)")
    operator_action: Literal["warn", "fallback", "hold-depth", "zero-thrust", "disarm"] = \
        setting("hold-depth", doc="the failsafe action on operator loss")
    manual_force_n: float = setting(
        50.0, unit="N", gt=0.0, max=10000.0,
        doc="MANUAL_CONTROL x, y, z at ±1000 map to this body force (surge, sway, heave)")
    manual_torque_nm: float = setting(
        10.0, unit="N m", gt=0.0, max=10000.0,
        doc="MANUAL_CONTROL r at ±1000 maps to this yaw torque")
    manual_timeout_s: float = setting(
        0.5, unit="s", gt=0.0, max=10.0,
        doc="a manual wrench holds this long after its MANUAL_CONTROL (then zero)")
    params_file: str = setting(
        "uvd-mavlink-params.toml",
        doc="parameters set over MAVLink are kept here and applied at the next start "
            "(relative to the working directory); empty: not kept")
    signing_key_file: str = setting(
        "", doc="MAVLink 2 signing: a file of the 32-byte secret key (raw, or 64 hex digits), "
                "readable by the owner only; commands must then be signed; empty: off")
    signing_timestamp_file: str = setting(
        "uvd-mavlink-signing.ts",
        doc="where the signing timestamp is kept across restarts (relative to the working "
            "directory)")

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        out = check_udp_address(self.listen, "listen", any_port=True) if self.listen else []
        for i, a in enumerate(self.connect):
            out += check_udp_address(a, f"connect[{i}]")
        return out


@dataclass(frozen=True)
class RecordingSection:
    """The black-box recorder (``[recording]``, docs/recording.md): every cycle record, event
    and raw input frame to MCAP files, written off the loop."""

    enabled: bool = setting(False, doc="record the run to MCAP (uvd demo --record turns it on)")
    dir: str = setting("uvd-recordings",
                       doc="folder of the .mcap files (relative to the working directory; "
                           "under systemd $STATE_DIRECTORY)")
    flush_interval_s: float = setting(
        0.25, unit="s", gt=0.0, max=1.0,
        doc="how often written data is handed to the operating system: after a crash or "
            "SIGKILL the file is readable up to at most this long before it")
    rotate_mb: float = setting(512.0, unit="MB", min=0.0, max=1e6,
                               doc="start a new file past this size; 0 never")
    rotate_s: float = setting(0.0, unit="s", min=0.0, max=1e7,
                              doc="start a new file after this long; 0 never")
    raw_queue_size: int = setting(
        65536, min=64, max=10_000_000,
        doc="raw frames that may wait for the writer; when full the oldest is dropped and "
            "counted (a replay of that stretch then reports the missing frames)")
    sync_interval_s: float = setting(
        1.0, unit="s", min=0.0, max=3600.0,
        doc="the files' data is forced to the disk (fdatasync, by the writer thread, off the "
            "loop) at most this long apart: what a power cut of the vehicle's computer may "
            "lose beside flush_interval_s; 0 leaves it to the operating system (on Linux up "
            "to ~30 s)")
    min_free_mb: float = setting(
        500.0, unit="MB", min=0.0, max=1e12,
        doc="the operator is told (STATUSTEXT, Zenoh event) when the recording's disk has "
            "less free than this, with the hours of recording left at the rate so far, and "
            "again when it has more; 0 never (ArduPilot's LOG_FILE_MB_FREE is 500 MB too)")


@dataclass(frozen=True)
class DaemonSection:
    """Start and stop of the daemon (``[daemon]``)."""

    start_timeout_s: float = setting(10.0, unit="s", gt=0.0, max=300.0,
                                     doc="drivers must be up within this time, else exit 1 (the "
                                         "links are waited for as long before them, then "
                                         "go on opening)")
    shutdown_zero_cycles: int = setting(3, min=1, max=100,
                                        doc="zero-current commands sent on shutdown")
    shutdown_zero_period_s: float = setting(0.01, unit="s", min=0.0, max=0.5,
                                            doc="interval between those commands")
    step_timeout_s: float = setting(0.5, unit="s", gt=0.0, max=10.0,
                                    doc="time allowed to each shutdown step (disable "
                                        "amplifiers, stop a driver, close a sink)")
    shutdown_timeout_s: float = setting(1.5, unit="s", gt=0.0, max=30.0,
                                        doc="the whole shutdown sequence (systemd "
                                            "TimeoutStopSec must be longer)")
    gil_switch_interval_us: float = setting(
        500.0, unit="µs", min=50.0, max=5000.0,
        doc="sys.setswitchinterval: how long another Python thread may hold the GIL while "
            "the loop waits for it")
    helper_thread_priority: int = setting(
        0, min=0, max=99,
        doc="SCHED_FIFO priority of every other thread of the daemon (logging, telemetry, CAN "
            "receive, workers) when [loop] sched_fifo_priority is set: a normally scheduled "
            "thread holding the GIL would make the loop wait while other load preempts it; "
            "0 (default) = leave them as they start (threads started after the loop took "
            "SCHED_FIFO inherit its priority), e.g. 49 = every one at 49, on the loop's CPUs. "
            "Experimental: a demo run with it at 49 once stalled its drivers; see "
            "docs/runtime.md")


@dataclass(frozen=True)
class SimInstrumentsSection:
    """The simulated instruments (``[simulation.instruments]``): rates and noise of the INS,
    DVL and depth sensor that ``sim-bridge`` emulates and a lockstep run of this configuration
    samples (``sim_bridge.instruments.models.InstrumentConfig``). Defaults: the JHU ROV's
    Table A.1. The daemon itself does not read them."""

    noise: bool = setting(True, doc="add the noise below (false: exact samples)")
    ins_rate_hz: float = setting(10.0, unit="Hz", gt=0.0, max=1000.0,
                                 doc="INS (PHINS III) output rate (Table A.1: 10)")
    heading_std_rad: float = setting(0.13 * math.pi / 180, unit="rad", min=0.0, max=1.0,
                                     doc="INS heading noise, standard deviation (0.13°)")
    roll_pitch_std_rad: float = setting(0.01 * math.pi / 180, unit="rad", min=0.0, max=1.0,
                                        doc="INS roll and pitch noise (0.01°)")
    rate_std_rad_s: float = setting(0.01 * math.pi / 180, unit="rad/s", min=0.0, max=1.0,
                                    doc="INS angular-rate noise (0.01°/s)")
    dvl_rate_hz: float = setting(6.0, unit="Hz", gt=0.0, max=1000.0,
                                 doc="DVL ping rate (Table A.1: 6)")
    dvl_std_m_s: float = setting(0.003, unit="m/s", min=0.0, max=1.0,
                                 doc="DVL velocity noise (0.003)")
    dvl_altitude_m: float = setting(2.0, unit="m", gt=0.0, max=1000.0,
                                    doc="the vehicle's height above the floor at depth 0")
    depth_rate_hz: float = setting(7.0, unit="Hz", gt=0.0, max=1000.0,
                                   doc="depth sensor rate (Table A.1: 7)")
    depth_std_m: float = setting(0.00075, unit="m", min=0.0, max=1.0,
                                 doc="depth noise (0.75 mm, sim_bridge.instruments.models)")
    xy_scale_error: float = setting(0.005, min=0.0, max=0.5,
                                    doc="DVLNAV dead-reckoning scale error bound (0.5 %)")


@dataclass(frozen=True)
class SimulationSection:
    """The simulated vehicle's side (``[simulation]``): read by ``sim-bridge`` and by the
    lockstep run of a configuration, never by the daemon."""

    instruments: SimInstrumentsSection = section(SimInstrumentsSection)


_ANY_HOST = {"0.0.0.0", "::", "[::]"}


def shared_ports(cfg: Config) -> list[tuple[str, str]]:
    """``[(key, why)]`` for each serial device two instruments name
    (:func:`_shared_devices`) and each UDP address the daemon binds that another of its own
    listeners binds already — a PHINS/DVL/depth ``udp://`` port, ``[mavlink] listen``,
    ``[telemetry.zenoh] listen`` ``udp/…`` — the same port on the same host or on the
    wildcard one. The second to bind failed at start ("start failed … Address already in
    use", found by probing in session 33: an INS on udp://127.0.0.1:14551, MAVLink's); an
    INS and a DVL on one device passed check-config."""
    binds: list[tuple[str, str, int]] = []
    for name in ("ins", "dvl", "depth"):
        m = _URL.match(getattr(cfg.sensors, name).port or "")
        if m and m.group(1) == "udp":
            binds.append((f"sensors.{name}.port", m.group("host"), int(m.group("port"))))
    if cfg.mavlink.enabled and cfg.mavlink.listen:
        host, _, port = cfg.mavlink.listen.rpartition(":")
        binds.append(("mavlink.listen", host, int(port)))
    if cfg.telemetry.zenoh.enabled:
        from uvd.zenoh_names import endpoint_address
        for i, ep in enumerate(cfg.telemetry.zenoh.listen):
            a = endpoint_address(ep)
            if a is not None and a[0] == "udp":
                binds.append((f"telemetry.zenoh.listen[{i}]", a[1], a[2]))
    out = _shared_devices(cfg)
    for k, (key, host, port) in enumerate(binds):
        for other, h, p in binds[:k]:
            if port and p == port and (h == host or {h, host} & _ANY_HOST):
                out.append((key, f"udp {host}:{port} is {other}'s too: the daemon's second "
                                 "listener there would fail to bind at start"))
                break
    return out


def _shared_devices(cfg: Config) -> list[tuple[str, str]]:
    """``[(key, why)]`` for an instrument's serial device that another instrument's port
    names too (the same path, or the same device through a link: /dev/serial/by-id/… and
    /dev/ttyUSB0): two readers on one device each get part of its bytes."""
    seen: dict[str, str] = {}
    out = []
    for name in ("ins", "dvl", "depth"):
        port = getattr(cfg.sensors, name).port
        if not port or not port.startswith("/") or (
                name == "depth" and cfg.sensors.depth.source != "serial"):
            continue
        key = f"sensors.{name}.port"
        real = os.path.realpath(port)
        other = seen.get(port) or seen.get(real)
        if other:
            out.append((key, f"{port!r} is {other}'s device too: two readers on one device "
                             "would each get part of its bytes"))
        seen.setdefault(port, key)
        seen.setdefault(real, key)
    return out


def short_deadline(timeout_ms: int, rate_hz: float) -> str | None:
    """Why the drives' RPDO deadline (0x1400:05) is too short for the loop's rate, or None.

    A missed deadline — an overrun, or the machine stalled for more than a period; the loop
    tolerates ``overrun_streak`` of them in a row — leaves the drives up to a period plus the
    stall without a command: more than two periods. Under two periods the drives fault
    between any two commands; under three, at the first missed deadline — measured before
    session 32 with the then shipped 200 ms at 10 Hz: the daemon stopped for 150 ms, one
    overrun, every drive timed out, amplifier_fault → disarm. 0 (a drive's own "off") is
    not short: see :func:`uvd.runtime.can_component.deadline_warnings`.
    """
    need_ms = 3e3 / rate_hz
    if timeout_ms == 0 or timeout_ms >= need_ms:
        return None
    return (f"{timeout_ms} ms is shorter than three cycles of [loop] rate_hz {rate_hz:g} "
            f"({need_ms:g} ms): the drives would time out at the first missed deadline")


@dataclass(frozen=True)
class Config:
    """The whole configuration file."""

    vehicle: VehicleSection = section(VehicleSection)
    loop: LoopSettings = section(LoopSettings)
    control: ControlSection = section(ControlSection)
    failsafe: Thresholds = section(Thresholds)
    navigation: NavigationSection = section(NavigationSection)
    estimation: EstimationSection = section(EstimationSection)
    sensors: SensorsSection = section(SensorsSection)
    can: CanConfig = section(CanConfig)
    telemetry: TelemetrySection = section(TelemetrySection)
    recording: RecordingSection = section(RecordingSection)
    mavlink: MavlinkSection = section(MavlinkSection)
    daemon: DaemonSection = section(DaemonSection)
    simulation: SimulationSection = section(SimulationSection)
    faults: FaultsSection = section(FaultsSection)
    source: str | None = field(default=None, init=False, compare=False)

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        out: list[tuple[str, str]] = []
        helper = self.daemon.helper_thread_priority
        if helper > self.loop.sched_fifo_priority:
            out.append(("daemon.helper_thread_priority",
                         f"{helper} is above [loop] sched_fifo_priority "
                         f"{self.loop.sched_fifo_priority} (helper threads must not preempt "
                         "the loop)"))
        z = self.telemetry.zenoh
        if z.enabled:  # the daemon's key space uvd/<key>/… (ZenohSink refuses it else)
            from uvd.zenoh_names import vehicle_key_problem
            key = z.key or Path(self.vehicle.name).stem
            why = vehicle_key_problem(key)
            if why:
                out.append(("telemetry.zenoh.key", f"{key!r}"
                            + ("" if z.key else " (the [vehicle] name's stem)") + f" {why}"))
        if self.faults.fdc.enabled and not self.telemetry.zenoh.enabled:
            out.append(("faults.fdc.enabled", "uvd-fdc's samples come over Zenoh: needs "
                                              "[telemetry.zenoh] enabled = true"))
        if self.sensors.depth.source == "can" and not self.can.depth.enabled:
            out.append(("sensors.depth.source", "\"can\" needs [can.depth] enabled = true"))
        out += shared_ports(self)
        if self.estimation.aid:  # AID steps once a cycle: its observer's step is the period
            from uvd.estimation.aid import observer_problem
            why = observer_problem(self.estimation.gains[0], 1.0 / self.loop.rate_hz)
            if why:
                out.append(("estimation.gains", f"{why} ([loop] rate_hz "
                                                 f"{self.loop.rate_hz:g})"))
        amps = self.can.amplifiers
        why = short_deadline(amps.command_timeout_ms, self.loop.rate_hz)
        if amps.configure and why:
            out.append(("can.amplifiers.command_timeout_ms", why))
        try:
            vehicle = self.load_vehicle(ctx.base_dir)
        except (ConfigError, ValueError, OSError) as exc:
            out.append(("vehicle.name", f"cannot load the vehicle: {exc}"))
        else:
            n = len(self.can.amplifiers.node_ids)
            if n != vehicle.n_thrusters:
                out.append(("can.amplifiers.node_ids",
                            f"{n} node ids for the {vehicle.n_thrusters} thrusters of "
                            f"{vehicle.name!r} (one per thruster, in the vehicle's order)"))
        return out

    def vehicle_ref(self, base_dir: Path | None = None) -> str:
        """Built-in vehicle name, or the vehicle file's path resolved against the config."""
        from uvd.io.vehicle import builtin_vehicles
        name = self.vehicle.name
        if name in builtin_vehicles():
            return name
        p = Path(name)
        if not p.is_absolute():
            base = base_dir or (Path(self.source).parent if self.source else Path.cwd())
            p = base / p
        return str(p)

    def load_vehicle(self, base_dir: Path | None = None):
        """The :class:`uvd.model.vehicle.Vehicle` of ``[vehicle]``."""
        from uvd.io.vehicle import load_vehicle
        return load_vehicle(self.vehicle_ref(base_dir))


# ------------------------------------------------------------------------------------ CAN
# The CAN driver keeps plain dataclasses (drivers/can/config.py; drivers never import uvd):
# the [can] tables are declared here, validated with everything else and converted.

@dataclass(frozen=True)
class CanAmplifiersSection:
    """The thruster amplifiers (``[can.amplifiers]``): one CiA 402 node per thruster."""

    node_ids: tuple[int, ...] = setting(
        (1, 2, 3, 4, 5, 6), min=1, max=127,
        doc="CANopen node id of each thruster's amplifier, in the vehicle's thruster order")
    eds: Path = setting(DEFAULT_AMPLIFIER_EDS, doc="object dictionary (EDS/DCF) of the "
                                                   "amplifier; the PDO mapping is taken from it")
    master_node_id: int = setting(127, min=1, max=127, doc="node id under which the daemon "
                                  "produces its heartbeat (0x700 + id); no amplifier's")
    mode: Literal["cst", "pt"] = setting(
        "cst", doc="cst: cyclic synchronous torque (0x6060 = 10); pt: profile torque (4)")
    heartbeat_period_ms: int = setting(100, unit="ms", min=0, max=10_000,
                                       doc="the daemon's heartbeat period, sent from the "
                                           "control cycle (a hung daemon stops it)")
    node_heartbeat_ms: int = setting(100, unit="ms", min=0, max=10_000,
                                     doc="heartbeat period written to each amplifier (0x1017)")
    heartbeat_timeout_ms: int = setting(350, unit="ms", min=1, max=60_000,
                                        doc="an amplifier whose heartbeat is older is "
                                            "reported heartbeat_lost")
    node_consumer_ms: int = setting(500, unit="ms", min=0, max=60_000,
                                    doc="heartbeat consumer time for the daemon's heartbeat "
                                        "written to each amplifier (0x1016:01); 0 = off; "
                                        "longer than heartbeat_period_ms")
    command_timeout_ms: int = setting(300, unit="ms", min=10, max=10_000,
                                      doc="RPDO deadline written to each amplifier (0x1400:05): "
                                          "without a command for this long it zeroes its "
                                          "output, sends EMCY 0x8250 and faults; at least "
                                          "three cycles of [loop] rate_hz (one missed "
                                          "deadline must not fault the drives)")
    max_failed_cycles: int = setting(5, min=1, max=1000,
                                     doc="consecutive cycles without feedback (per node) or "
                                         "with a failed send (per group) before a fault")
    thrust_per_permille_n: tuple[float, ...] | None = setting(
        None, unit="N", gt=0, doc="steady-state calibration, thrust per 1/1000 of rated "
                                  "torque, one per node id; absent: max_thrust_n / 1000 of "
                                  "each thruster")
    max_torque_permille: int = setting(1000, min=1, max=32767,
                                       doc="largest target torque ever sent (also 0x6072)")
    velocity_rad_s_per_count: float = setting(0.001, unit="rad/s", gt=0,
                                              doc="unit of the velocity actual value (0x606C)")
    configure: bool = setting(True, doc="write the objects above to every amplifier by SDO "
                                        "at start; false leaves the drives as they are "
                                        "(the daemon reads their own RPDO deadline and "
                                        "warns when it is off or shorter than three "
                                        "cycles)")
    sdo_timeout_s: float = setting(0.3, unit="s", min=0.01, max=5,
                                   doc="time allowed for one SDO response")

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        out = []
        if len(self.node_ids) == 0:
            out.append(("node_ids", "needs at least one node id"))
        if len(set(self.node_ids)) != len(self.node_ids):
            out.append(("node_ids", f"{list(self.node_ids)}: node ids must be distinct"))
        if self.master_node_id in self.node_ids:
            out.append(("master_node_id", f"{self.master_node_id} is an amplifier's node id"))
        if self.node_consumer_ms and not self.heartbeat_period_ms:
            out.append(("node_consumer_ms", "the amplifiers would consume a heartbeat the "
                                            "daemon does not produce (heartbeat_period_ms = 0)"))
        elif self.node_consumer_ms and self.node_consumer_ms <= self.heartbeat_period_ms:
            out.append(("node_consumer_ms", f"{self.node_consumer_ms} must be longer than "
                                            f"heartbeat_period_ms {self.heartbeat_period_ms} "
                                            "(or 0)"))
        t = self.thrust_per_permille_n
        if t is not None and len(t) != len(self.node_ids):
            out.append(("thrust_per_permille_n", f"{len(t)} values for {len(self.node_ids)} "
                                                 "node ids (one per node id)"))
        return out  # every number is finite: the schema refuses nan and inf

    def convert(self) -> AmplifierConfig:
        return AmplifierConfig(**{**vars(self), "eds": self.eds.expanduser()})


@dataclass(frozen=True)
class CanDepthSection:
    """A CiA 404 pressure transmitter as a depth source (``[can.depth]``): d = (p − p_atm)/(ρg).
    """

    enabled: bool = setting(False, doc="use the transmitter")
    node_id: int = setting(32, min=1, max=127, doc="its CANopen node id (no amplifier's, not "
                                                   "the daemon's)")
    eds: Path = setting(DEFAULT_PRESSURE_EDS, doc="its object dictionary (EDS/DCF)")
    pressure_pa_per_count: float = setting(0.1, unit="Pa", gt=0, doc="unit of the AI value")
    atmospheric_pa: float = setting(101_325.0, unit="Pa", min=0, max=2e5,
                                    doc="pressure at the surface")
    density_kg_m3: float = setting(998.0, unit="kg/m³", gt=0, doc="water density ρ")
    gravity_m_s2: float = setting(9.80665, unit="m/s²", gt=0, doc="gravity g")
    max_age_ms: int = setting(500, unit="ms", min=1, doc="a sample older than this is stale")

    def convert(self) -> CanDepthConfig:
        return CanDepthConfig(**{**vars(self), "eds": self.eds.expanduser()})


@dataclass(frozen=True)
class CanLogSection:
    """Recording of every frame sent and received (``[can.log]``, python-can writers)."""

    path: Path | None = setting(None, doc="the file; its suffix picks the format: .log "
                                          "(candump), .asc (Vector ASCII), .blf (Vector "
                                          "binary); absent: nothing recorded")
    max_bytes: int = setting(0, unit="B", min=0, doc="rotate the file past this size; 0 = never")

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        if self.path is not None and self.path.suffix.lower() not in LOG_SUFFIXES:
            return [("path", f"{str(self.path)!r} must end in one of "
                             f"{', '.join(LOG_SUFFIXES)}")]
        return []

    def convert(self) -> CanLogConfig:
        return CanLogConfig(path=None if self.path is None else self.path.expanduser(),
                            max_bytes=self.max_bytes)


@dataclass(frozen=True)
class CanSection:
    """The CAN bus (``[can]``): how to open it and how to judge its health."""

    interface: str = setting("socketcan", doc="python-can interface: socketcan, slcan, pcan, "
                                              "virtual, udp_multicast, …")
    channel: str = setting("can0", doc="its channel: can0, /dev/ttyACM0, PCAN_USBBUS1, any "
                                       "name (virtual), a multicast group (udp_multicast)")
    bitrate: int | None = setting(1_000_000, unit="bit/s", min=10_000, max=8_000_000,
                                  doc="for interfaces that take one (not virtual, "
                                      "udp_multicast, nor socketcan: set with ip link)")
    port: int = setting(DEFAULT_UDP_PORT, min=1, max=65535, doc="UDP port of udp_multicast")
    loopback_only: bool = setting(True, doc="udp_multicast: refuse a group whose packets could "
                                            "leave this machine (anything but an "
                                            "interface-local ff11:: IPv6 group); hop limit 0")
    send_timeout_s: float = setting(0.0, unit="s", min=0, max=0.1,
                                    doc="how long a send may wait for room in the transmit "
                                        "queue; 0: a full queue drops the frame at once")
    busoff_send_failures: int = setting(10, min=1, doc="consecutive failed sends after which "
                                                       "the bus is taken as bus-off")
    busoff_holdoff_s: float = setting(0.2, unit="s", min=0, doc="after bus-off, sends are "
                                      "suppressed this long before the bus is probed again")
    error_passive_frames: int = setting(32, min=1, doc="bus-error frames within one second "
                                        "taken as error-passive when the interface reports no "
                                        "error counters")
    reopen_after_s: float = setting(1.0, unit="s", gt=0, doc="the bus is closed and opened "
                                    "again when reception, or every send, has failed this long")
    reopen_backoff_s: tuple[float, float] = setting(
        (0.5, 10.0), unit="s", gt=0, doc="first and largest wait between reopen attempts "
                                         "(doubling)")
    options: dict[str, Any] = setting({}, doc="extra keyword arguments for can.Bus (e.g. "
                                             "{serial_port = …})")
    amplifiers: CanAmplifiersSection = section(CanAmplifiersSection)
    depth: CanDepthSection = section(CanDepthSection)
    log: CanLogSection = section(CanLogSection)

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        out = []
        try:
            from can.interfaces import VALID_INTERFACES
        except ImportError:  # pragma: no cover - python-can is a dependency
            VALID_INTERFACES = ()
        if VALID_INTERFACES and self.interface not in VALID_INTERFACES:
            out.append(("interface", f"{self.interface!r} is not a python-can interface "
                                     f"({', '.join(sorted(VALID_INTERFACES))})"))
        if not self.channel:
            out.append(("channel", "must not be empty"))
        first, largest = self.reopen_backoff_s
        if first > largest:
            out.append(("reopen_backoff_s", f"first {first:g} s is above largest {largest:g} s"))
        if self.interface == "udp_multicast":
            out += self._check_group()
        amps = self.amplifiers
        if self.depth.enabled and self.depth.node_id in amps.node_ids + (amps.master_node_id,):
            out.append(("depth.node_id", f"{self.depth.node_id} is already used by an "
                                         "amplifier or the daemon"))
        return out

    def _check_group(self) -> list[tuple[str, str]]:
        try:
            group = ipaddress.ip_address(self.channel)
        except ValueError:
            return [("channel", f"udp_multicast needs a multicast IP group, got "
                                f"{self.channel!r}")]
        if not group.is_multicast:
            return [("channel", f"{self.channel!r} is not a multicast group")]
        scope = int(group) >> 112 & 0xF if group.version == 6 else None
        if self.loopback_only and scope != 1:
            return [("channel", f"{self.channel!r} could leave this machine; with "
                                "loopback_only = true use an interface-local IPv6 group "
                                f"(ff11::/16, e.g. {DEFAULT_UDP_GROUP!r}) or set "
                                "loopback_only = false deliberately")]
        return []

    def convert(self) -> CanConfig:
        keys = ("interface", "channel", "bitrate", "port", "loopback_only", "send_timeout_s",
                "busoff_send_failures", "busoff_holdoff_s", "error_passive_frames",
                "reopen_after_s", "reopen_backoff_s", "options")
        return CanConfig(bus=CanBusConfig(**{k: getattr(self, k) for k in keys}),
                         amplifiers=self.amplifiers.convert(), depth=self.depth.convert(),
                         log=self.log.convert())


schema.DECLARED_BY[CanConfig] = CanSection


# ------------------------------------------------------------------------------ loading

def parse_config(data: dict[str, Any], *, source: str | Path | None = None) -> Config:
    """Validate an already parsed TOML mapping; raises :class:`ConfigValidationError`."""
    where = str(source) if source is not None else "<config>"
    ctx = schema.BuildContext(Path(source) if source is not None else None)
    kind = other_kind(data, "configuration")
    if kind and not set(data) & {f.name for f in dataclasses.fields(Config)} - {"vehicle"}:
        raise ConfigValidationError(where, [("", f"this is {kind}, not a daemon "
                                                 "configuration")])
    cfg, errors = schema.build(Config, data, ctx=ctx)
    if errors or cfg is None:
        raise ConfigValidationError(where, errors)
    object.__setattr__(cfg, "source", str(source) if source is not None else None)
    return cfg


def load_config(path: str | Path | None = None) -> Config:
    """Read and validate a TOML configuration file (default: :data:`DEFAULT_CONFIG`; a bare
    name is a shipped configuration, :func:`config_path`).

    Raises
    ------
    ConfigValidationError
        Unreadable file, TOML syntax error, or any schema violation — one line per problem
        naming the file, the dotted key and the reason.
    """
    path = config_path(path) if path is not None else DEFAULT_CONFIG
    try:
        data = read_toml(path)
    except TomlFileError as exc:
        reason = exc.reason
        if isinstance(exc.__cause__, FileNotFoundError) and len(Path(path).parts) == 1:
            reason += f", nor a shipped configuration's name ({', '.join(shipped_configs())})"
        raise ConfigValidationError(str(path), [("", reason)]) from exc
    return parse_config(data, source=path)


# ------------------------------------------------------------------------------ docs

def _md(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def render_config_doc() -> str:
    """``docs/config.md``: every table and key of :class:`Config`, generated from the schema."""
    lines = [
        "# Configuration reference",
        "",
        "<!-- GENERATED by `uvd check-config --doc-out docs/config.md` from the schema in",
        "     uvd/runtime/config.py (and the sections it plugs in). Do not edit by hand. -->",
        "",
        "uvd reads one TOML file (`uvd run --config FILE`; the embedded default is",
        "`config/sim.toml`). `uvd check-config FILE` validates it without starting anything;",
        "every error names the file, the dotted key and the reason. Unknown keys are errors,",
        "and so is a number that is not finite (`nan`, `inf`).",
        "Keys marked *reload* may change on `SIGHUP` (`systemctl reload uvd`); changing any",
        "other key needs a restart, and a reload says which ones it kept.",
        "",
        "Examples: `config/sim.toml` (simulated vehicle, everything local) and",
        "`config/jhu-rov.toml` (the real vehicle; ports and CAN ids are placeholders).",
        "",
    ]
    for table, doc, keys in schema.describe(Config):
        lines.append(f"## `[{table}]`")
        lines.append("")
        if doc:
            lines += [_md(doc), ""]
        lines.append("| key | type | unit | default | allowed | reload | description |")
        lines.append("| --- | --- | --- | --- | --- | --- | --- |")
        for k in keys:
            short = k.key.rsplit(".", 1)[-1]
            lines.append(f"| `{short}` | {_md(k.type)} | {_md(k.unit)} | {_md(k.default)} | "
                         f"{_md(k.constraint)} | {'yes' if k.reload else ''} | {_md(k.doc)} |")
        lines.append("")
    return "\n".join(lines)
