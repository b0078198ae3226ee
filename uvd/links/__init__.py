"""Every face of the daemon: what leaves it and what enters it besides sensors and amplifiers.

Each face is a sink of the one :class:`~uvd.telemetry.sink.TelemetryHub` (bounded,
drop-oldest, counted; never on the loop's critical path), and a link that takes commands
queues them on the App's command queue for the next cycle:

* :mod:`uvd.links.mavlink` — the ground-station link (docs/mavlink.md): the link, its
  receiver process, the parameters it exposes, message signing;
* :mod:`uvd.links.zenoh` — state, estimates and health for fault-detection clients
  (docs/zenoh.md);
* :mod:`uvd.links.mcap` — the black-box recorder (docs/recording.md);
* :mod:`uvd.links.jsonl` — every record as a JSON line;
* :mod:`uvd.links.params_file` — the newest online estimate θ̂ kept as a parameters file.

The faces are registered by name in one place, :data:`LINKS` (python-can's backends are the
model: name → factory): the :class:`~uvd.runtime.app.App` calls every factory with a
:class:`LinkContext` and adds each face the configuration enables to its hub, in the order of
the registry. A factory imports its face's module when the face is enabled, so a daemon without
Zenoh or MAVLink never loads zenoh or pymavlink.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from uvd.runtime.commands import CommandQueue
    from uvd.runtime.config import Config
    from uvd.telemetry.sink import TelemetryHub, TelemetrySink

__all__ = ["LINKS", "Face", "LinkContext"]


@dataclass
class LinkContext:
    """What a face is built from.

    Attributes
    ----------
    config : Config
        The configuration at start (the faces' own sections need a restart to change).
    hub : TelemetryHub
        The hub the faces are added to.
    commands : CommandQueue
        Where a link queues the commands it receives (applied at the next cycle boundary).
    running_config : callable
        The configuration in force now (after reloads and parameters set at run time).
    """

    config: Config
    hub: TelemetryHub
    commands: CommandQueue
    running_config: Callable[[], Config]

    @cached_property
    def vehicle(self) -> Any:
        """The configured vehicle (loaded once, for the faces that describe it)."""
        return self.config.load_vehicle()


@dataclass(frozen=True)
class Face:
    """One configured face: the sink the hub feeds, one cycle record in ``every_n``, and only
    records of ``types`` when given."""

    sink: TelemetrySink
    every_n: int = 1
    types: tuple[str, ...] | None = None


def _mcap(ctx: LinkContext) -> Face | None:
    """``[recording]``: the black box (docs/recording.md)."""
    r = ctx.config.recording
    if not r.enabled:
        return None
    from uvd.links.mcap import McapRecorder
    return Face(McapRecorder(r.dir, flush_interval_s=r.flush_interval_s, rotate_mb=r.rotate_mb,
                             rotate_s=r.rotate_s, raw_queue_size=r.raw_queue_size,
                             min_free_mb=r.min_free_mb, sync_interval_s=r.sync_interval_s))


def _jsonl(ctx: LinkContext) -> Face | None:
    """``[telemetry.jsonl]``: every record as a JSON line."""
    j = ctx.config.telemetry.jsonl
    if not j.enabled:
        return None
    from uvd.links.jsonl import JsonLinesSink
    return Face(JsonLinesSink(j.path), every_n=j.every_n_cycles)


def _zenoh(ctx: LinkContext) -> Face | None:
    """``[telemetry.zenoh]``: state, estimates and health for clients (docs/zenoh.md)."""
    if not ctx.config.telemetry.zenoh.enabled:
        return None
    from uvd.links.zenoh import zenoh_sink
    return Face(zenoh_sink(ctx.config, ctx.hub, vehicle=ctx.vehicle, commands=ctx.commands))


def _mavlink(ctx: LinkContext) -> Face | None:
    """``[mavlink]``: the ground-station link (docs/mavlink.md)."""
    c = ctx.config
    if not c.mavlink.enabled:
        return None
    from uvd.links.mavlink.link import MavlinkLink
    f = c.failsafe
    return Face(MavlinkLink(
        c.mavlink, ctx.commands, ctx.running_config,
        thresholds={"ins": f.ins_stale_s, "dvl": f.dvl_stale_s, "depth": f.depth_stale_s,
                    "feedback": f.feedback_stale_s},
        max_thrust_n=ctx.vehicle.max_thrust_n, controller=c.control.controller,
        step1_s=c.control.step1_duration_s, loop_cpus=c.loop.cpu_affinity,
        recorders=[name for name, on in (("mcap", c.recording.enabled),
                                         ("jsonl", c.telemetry.jsonl.enabled),
                                         ("canlog", c.can.log.path is not None)) if on]))


def _params_file(ctx: LinkContext) -> Face | None:
    """``[estimation] save_path``: the online estimate θ̂ kept as a parameters file."""
    est = ctx.config.estimation
    if not (est.aid and est.save_path):
        return None
    from uvd.links.params_file import RECORD_TYPE, ParamsFileSink
    return Face(ParamsFileSink(est.save_path, every_s=est.save_every_s), types=(RECORD_TYPE,))


#: name → factory of every face; a factory returns None when the configuration leaves its face
#: off. The order is the order the hub feeds them.
LINKS: dict[str, Callable[[LinkContext], Face | None]] = {
    "mcap": _mcap,
    "jsonl": _jsonl,
    "zenoh": _zenoh,
    "mavlink": _mavlink,
    "params_file": _params_file,
}
