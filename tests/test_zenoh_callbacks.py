"""A Zenoh session's Python callbacks end with it (uvd.zenoh_callbacks): zenoh-python runs
each on a thread of its own that ``Session.close()`` does not wait for, and a process that
exits while one is still running can abort in Python's finalization. Real sessions on
loopback; a callback held inside itself by an event, so the order is certain, not timed."""

from __future__ import annotations

import ast
import asyncio
import json
import threading
import time
from pathlib import Path

import zenoh

from uvd.links.zenoh import ZenohSink, zenoh_config
from uvd.netports import free_port
from uvd.zenoh_callbacks import SessionCallbacks


def _held_callback():
    """A callback that, at its first sample, signals ``inside`` and stays until ``release``;
    returns (callback, inside, release, the thread it ran on)."""
    inside, release, ran_on = threading.Event(), threading.Event(), []

    def callback(_sample) -> None:
        ran_on.append(threading.current_thread())
        inside.set()
        release.wait(10.0)
    return callback, inside, release, ran_on


def _release_later(release: threading.Event, after_s: float) -> threading.Thread:
    t = threading.Timer(after_s, release.set)
    t.start()
    return t


def test_plain_close_leaves_a_callback_running_and_session_callbacks_wait_for_it():
    conf = zenoh_config(listen=[f"tcp/127.0.0.1:{free_port()}"])
    # the premise: Session.close() returns while the callback's thread is still inside it
    callback, inside, release, ran_on = _held_callback()
    s = zenoh.open(conf)
    s.declare_subscriber("t/**", callback)
    s.put("t/x", "1")
    assert inside.wait(5.0)
    s.close()
    assert ran_on[0].is_alive() and ran_on[0] is not threading.current_thread()
    release.set()
    ran_on[0].join(5.0)

    # the mend: close() returns once that thread has left the callback and ended
    callback, inside, release, ran_on = _held_callback()
    s = zenoh.open(zenoh_config(listen=[f"tcp/127.0.0.1:{free_port()}"]))
    callbacks = SessionCallbacks()
    s.declare_subscriber("t/**", callbacks(callback))
    s.declare_queryable("t/q", callbacks(lambda _q: None))  # never called: ends at the close
    s.liveliness().declare_subscriber("t/alive", callbacks(lambda _s: None), history=True)
    s.put("t/x", "1")
    assert inside.wait(5.0)
    timer = _release_later(release, 0.3)
    t0 = time.monotonic()
    running = callbacks.close(s)
    waited = time.monotonic() - t0
    left = [t for t in threading.enumerate() if t.name.endswith("(pyo3-closure)")]
    timer.join()
    assert running == 0 and not ran_on[0].is_alive() and not left, left
    assert waited >= 0.25, waited  # it did wait for the callback (released after 0.3 s)


def test_a_callback_that_outlasts_the_timeout_is_counted_not_waited_for_ever():
    callback, inside, release, ran_on = _held_callback()
    s = zenoh.open(zenoh_config(listen=[f"tcp/127.0.0.1:{free_port()}"]))
    callbacks = SessionCallbacks()
    s.declare_subscriber("t/**", callbacks(callback))
    s.put("t/x", "1")
    assert inside.wait(5.0)
    t0 = time.monotonic()
    told: list[str] = []
    try:
        assert callbacks.close(s, timeout_s=0.2, warn=told.append, who="uvd-fdc") == 1
        assert time.monotonic() - t0 < 2.0
        assert told == ["uvd-fdc: 1 callback(s) still running 0.2 s after the session closed"]
    finally:
        release.set()
        ran_on[0].join(5.0)


def test_the_daemons_sink_ends_its_fault_callback_before_its_close_returns():
    """The daemon's Zenoh sink: a fault sample whose hand-over to the daemon is still under
    way when the sink closes (the daemon shutting down) is waited for; nothing of the session
    is left running when ``aclose`` returns, so the process exits cleanly."""
    port = free_port()
    inside, release = threading.Event(), threading.Event()
    got = []

    def faults(report) -> None:  # the daemon's command queue's put, held here
        got.append(report)
        inside.set()
        release.wait(10.0)

    sink = ZenohSink("rov9", zenoh_config(listen=[f"tcp/127.0.0.1:{port}"]), faults=faults)
    sample = {"kind": "thruster", "channel": "thruster4", "t_ns": 5, "confidence": 3.0,
              "relative_change": -0.5}

    async def main() -> float:
        await sink.open()
        with zenoh.open(zenoh_config(connect=[f"tcp/127.0.0.1:{port}"])) as fdc:
            deadline = time.monotonic() + 10.0
            while not inside.is_set() and time.monotonic() < deadline:  # until it is routed
                fdc.put("uvd/rov9/fault/thruster", json.dumps(sample))
                await asyncio.sleep(0.1)
        assert inside.is_set()
        timer = _release_later(release, 0.3)
        t0 = time.monotonic()
        await sink.aclose()
        waited = time.monotonic() - t0
        left = [t for t in threading.enumerate() if t.name.endswith("(pyo3-closure)")]
        timer.join()
        return waited, left

    waited, left = asyncio.run(main())
    assert got and got[0].channel == "thruster4"
    assert not left and waited >= 0.25, (waited, left)


# --- every Python callback handed to zenoh goes through SessionCallbacks ----------------------

#: the calls that take a handler, and where it is when given by position
_HANDLER_CALLS = {"declare_subscriber": 1, "declare_queryable": 1}
#: this file's first test hands zenoh plain callbacks on purpose (the premise it shows)
_PLAIN_ON_PURPOSE = {"tests/test_zenoh_callbacks.py"}


def bare_callbacks(source: str) -> list[int]:
    """Lines where a handler given to ``declare_subscriber`` / ``declare_queryable`` is not
    ``callbacks(fn)`` (any name ending in ``callbacks``: a :class:`SessionCallbacks`). A call
    with no handler (zenoh's channel, read by the caller) starts no thread and is fine."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and node.func.attr in _HANDLER_CALLS):
            continue
        at = _HANDLER_CALLS[node.func.attr]
        handler = node.args[at] if len(node.args) > at else next(
            (k.value for k in node.keywords if k.arg == "handler"), None)
        if handler is None:
            continue
        f = handler.func if isinstance(handler, ast.Call) else None
        name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) \
            else ""
        if not name.endswith("callbacks"):
            lines.append(node.lineno)
    return lines


def test_the_scan_finds_a_bare_callback_and_passes_a_wrapped_one():
    assert bare_callbacks('s.declare_subscriber("k", lambda x: None)') == [1]
    assert bare_callbacks('s.declare_queryable("k", handler=on_query)') == [1]
    assert bare_callbacks('s.liveliness().declare_subscriber("k",\n on_alive, history=True)') \
        == [1]
    assert bare_callbacks('s.declare_subscriber("k", callbacks(on_x))') == []
    assert bare_callbacks('s.declare_queryable("k", handler=self._callbacks(self.on_q))') == []
    assert bare_callbacks('sub = s.declare_subscriber("k")') == []  # a channel: no thread


def test_no_callback_is_handed_to_zenoh_bare():
    """A callback not wrapped by SessionCallbacks keeps a thread that the session's close does
    not end (the abort this module's docstring tells of), in the daemon's packages and in the
    tests' own processes alike."""
    root = Path(__file__).resolve().parents[1]
    found = []
    for folder in ("uvd", "drivers", "sim_bridge", "tests"):
        for path in sorted((root / folder).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            if rel in _PLAIN_ON_PURPOSE:
                continue
            found += [f"{rel}:{n}" for n in bare_callbacks(path.read_text(encoding="utf-8"))]
    assert not found, "callbacks handed to zenoh without SessionCallbacks: " + ", ".join(found)
