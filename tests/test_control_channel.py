"""The emulator processes' JSON-lines control channel (sim_bridge/control_channel.py)."""

from __future__ import annotations

import io
import json

from sim_bridge.control_channel import JsonLines, serve_commands


def _serve(text: str) -> tuple[list[dict], list[tuple], list[bool]]:
    out = io.StringIO()
    calls: list[tuple] = []
    ended: list[bool] = []

    def call(op, **kw):
        calls.append((op, kw))
        return {"ok": True, "op": op}

    serve_commands(call, JsonLines(out), lambda: ended.append(True), io.StringIO(text))
    return [json.loads(x) for x in out.getvalue().splitlines()], calls, ended


def test_each_command_is_answered_with_its_id_and_quit_ends_the_channel():
    answers, calls, ended = _serve('{"op": "stats", "id": 1}\n\n{"op": "fault", "node": 2}\n'
                                   '{"op": "quit", "id": 9}\n{"op": "never", "id": 10}\n')
    assert calls == [("stats", {}), ("fault", {"node": 2})]
    assert answers == [{"id": 1, "ok": True, "op": "stats"},
                       {"id": None, "ok": True, "op": "fault"}, {"id": 9, "ok": True}]
    assert ended == [True]


def test_malformed_lines_are_answered_named_and_skipped():
    answers, calls, ended = _serve('not json\n{"id": 3}\n[1, 2]\n{"op": "stats", "id": 4}\n')
    assert [a["ok"] for a in answers] == [False, False, False, True]
    assert "not json" in answers[0]["error"] and "'op'" in answers[1]["error"]
    assert calls == [("stats", {})]
    assert ended == [True]  # end of input (the parent gone) ends it too
