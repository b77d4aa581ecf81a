"""JSON Lines, UDP and WebSocket sinks, sink strings and target choice."""

from __future__ import annotations

import asyncio
import json
import socket

import numpy as np
import pytest

from drovisio.pipeline import FrameOutput
from drovisio.sinks import SinkError, open_sink
from drovisio.sinks.target import TargetSelector, parse_target
from drovisio.tracking import TrackedBrick


def _brick(layout, instance, track, x, z):
    return TrackedBrick(layout, instance, track, "aruco", np.array([3.1, 0, 0]),
                        np.array([x, 0.0, z]), np.eye(6) * 1e-4, 5.0, 5.0, 0.0, True)


def _output(bricks=None):
    bricks = bricks if bricks is not None else [_brick("a", 1, 1, 0.1, 1.0),
                                                 _brick("b", None, 2, -0.3, 0.8)]
    return FrameOutput("cam", 3, 3, 5.0, 5.0, bricks, target=bricks[0] if bricks else None)


def test_target_selection():
    bricks = [_brick("a", 1, 1, 0.1, 1.0), _brick("a", 2, 2, 0.0, 2.0),
              _brick("b", None, 3, 0.3, 0.5)]
    sel = TargetSelector()
    assert sel.choose(bricks).track == 3  # nearest
    assert sel.set("a").mode == "layout" and sel.choose(bricks).track == 1
    sel.set("a:2")
    assert sel.choose(bricks).track == 2
    sel.set({"mode": "track", "track": 3})
    assert sel.choose(bricks).track == 3
    sel.set("none")
    assert sel.choose(bricks) is None
    sel.set("a:7")
    assert sel.choose(bricks) is None
    with pytest.raises(ValueError):
        parse_target("a:x")
    assert str(parse_target({"layout": "a", "instance": 2})) == "a:2"


def test_a_target_the_layouts_in_use_cannot_have_is_refused():
    from drovisio.layout import load_layouts, shipped_layouts_dir

    root = shipped_layouts_dir()
    layouts = load_layouts([root / "drick-aruco-centre.json", root / "drick-dots-2x3.json"])
    sel = TargetSelector(layouts=layouts)
    refused = {
        "track:-1": "track number: -1 is out of range: give a whole number 1 or more",
        "drick-aruco-centre:20": "drick-aruco-centre has instances 0 to 19; 20 is not one "
                                 "of them",
        "drick-aruco-centre:-1": "instance (LAYOUT:INSTANCE): -1 is out of range: give a "
                                 "whole number 0 or more",
        "drick-dots-2x3:0": "the bricks of drick-dots-2x3 have no ids, so no instance number; "
                            "give drick-dots-2x3 or track:N",
        "drick:1": "no layout named 'drick' is in use (in use: drick-aruco-centre, "
                   "drick-dots-2x3)",
    }
    for spec, why in refused.items():
        with pytest.raises(ValueError) as e:
            sel.set(spec)
        assert str(e.value) == why, spec
    assert str(sel.spec) == "nearest"  # a refused spec changes nothing
    with pytest.raises(ValueError, match="track number"):
        sel.set({"mode": "track", "track": -1})
    assert str(sel.set("drick-aruco-centre:19")) == "drick-aruco-centre:19"
    assert str(sel.set("drick-dots-2x3")) == "drick-dots-2x3"
    with pytest.raises(ValueError, match="no layout named 'x'"):
        TargetSelector("x:1", layouts=layouts)


def test_jsonl_file_and_bad_specs(tmp_path):
    s = open_sink(f"jsonl:{tmp_path / 'sub' / 'o.jsonl'}")
    s.send(_output())
    s.send(_output([]))
    s.close()
    lines = [json.loads(x) for x in (tmp_path / "sub" / "o.jsonl").read_text().splitlines()]
    assert lines[0]["bricks"][0]["layout"] == "a" and lines[0]["target"]["track"] == 1
    assert lines[1]["bricks"] == [] and lines[1]["target"] is None
    for bad in ["tcp://x:1", "udp://nohostport", "jsonl:/proc/forbidden/x.jsonl"]:
        with pytest.raises(SinkError):
            open_sink(bad)


def test_a_jsonl_file_is_appended_to_and_one_never_written_is_not_made(tmp_path):
    """An existing file is opened at start and never truncated; a missing one (and its
    folders) is made at the first line, so a sink that got none leaves nothing behind, and a
    sink never removes a file."""
    kept, empty = tmp_path / "kept.jsonl", tmp_path / "empty.jsonl"
    kept.write_bytes(b"earlier\n")
    empty.touch()
    for path in (kept, empty, tmp_path / "new.jsonl", tmp_path / "a" / "b" / "new.jsonl"):
        s = open_sink(f"jsonl:{path}")
        s.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.jsonl", "kept.jsonl"]
    assert (kept.read_bytes(), empty.read_bytes()) == (b"earlier\n", b"")
    s = open_sink(f"jsonl:{kept}")
    s.send(_output([]))
    s.close()
    assert kept.read_text().splitlines()[0] == "earlier"
    s = open_sink(f"jsonl:{tmp_path / 'a' / 'o.jsonl'}")
    assert not (tmp_path / "a").exists()
    s.send(_output([]))
    s.close()
    s.close()
    assert json.loads((tmp_path / "a" / "o.jsonl").read_text())["bricks"] == []
    assert [p.name for p in (tmp_path / "a").iterdir()] == ["o.jsonl"]   # no check left


def test_udp_datagram_and_no_listener():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(2)
    s = open_sink(f"udp://127.0.0.1:{rx.getsockname()[1]}")
    s.send(_output())
    d = json.loads(rx.recv(65536))
    assert d["frame"] == 3 and len(d["bricks"]) == 2
    rx.close()
    for _ in range(3):  # nobody listens any more: counted, never raised
        s.send(_output())
    s.close()
    assert s.status()["sent"] + s.status()["errors"] == 4


def test_websocket_feed_and_runtime_target():
    from websockets.asyncio.client import connect

    sel = TargetSelector()
    s = open_sink("ws://127.0.0.1:0", target=sel)

    async def client():
        async with connect(f"ws://127.0.0.1:{s.port}") as ws:
            for _ in range(50):
                if s.clients:
                    break
                await asyncio.sleep(0.02)
            s.send(_output())
            d = json.loads(await asyncio.wait_for(ws.recv(), 3))
            assert d["frame"] == 3
            await ws.send(json.dumps({"set_target": "a:2"}))
            r = json.loads(await asyncio.wait_for(ws.recv(), 3))
            assert r["target"]["spec"] == "a:2"
            await ws.send(json.dumps({"set_target": "a:x"}))
            assert "error" in json.loads(await asyncio.wait_for(ws.recv(), 3))

    asyncio.run(client())
    s.close()
    assert str(sel.spec) == "a:2"
