"""A sink that cannot open is one line, ``drovisio run: --sink SPEC: why; what to do``: the
option and the spec said once (by ``open_sink``, the one way every sink is opened, whatever
the sink's own words), exit 2, no traceback."""

from __future__ import annotations

from pathlib import Path

import pytest

from drovisio.cli import main
from drovisio.sinks import SinkError, open_sink

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_sessions"


def _refusals(port: int) -> list[tuple[str, str]]:
    """(SINK string, the line's words after ``--sink SPEC: ``) for each kind of sink, in a
    folder that holds a file ``a-file``; ``port`` one nothing listens on (a connect to it is
    refused at once)."""
    return [
        ("jsonl:a-file/x.jsonl",
         "cannot write in a-file (not a folder); give a file in a folder that exists (or can "
         "be made) and that this user can write to"),
        ("zenoh:connect=foo",
         "connect: 'foo' is not a Zenoh endpoint: write a Zenoh endpoint as tcp/HOST:PORT, "
         "e.g. tcp/0.0.0.0:7447"),
        ("zenoh:mode=client&listen=tcp/0.0.0.0:7447",
         "mode=client needs connect=tcp/HOST:PORT (a router)"),
        (f"mavlink:tcp:127.0.0.1:{port}",
         f"cannot connect to 127.0.0.1:{port} (Connection refused); is the autopilot (or its "
         "TCP bridge) listening there?"),
        ("mavlink:udpout:127.0.0.1:14550?sysid=999",
         "sysid: expected a whole number 1-255, got '999'"),
        ("ws://127.0.0.1:99999",
         "expected ws://HOST:PORT with a port 0-65535, e.g. ws://127.0.0.1:8765"),
        ("udp://nohostport",
         "expected udp://HOST:PORT with a port 1-65535, e.g. udp://127.0.0.1:9870"),
        ("bogus:x",
         "unknown sink: use jsonl:-, jsonl:PATH, udp://HOST:PORT, mavlink:CONNECTION, "
         "ws://HOST:PORT or zenoh:connect=tcp/HOST:PORT"),
    ]


def test_every_sink_that_cannot_open_is_one_line_naming_its_spec_once(tmp_path, capsys,
                                                                      monkeypatch, free_port):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a-file").write_text("")
    for spec, why in _refusals(free_port()):
        rc = main(["run", "--source", str(SAMPLE / "approach" / "approach.mp4"),
                   "--camera", str(SAMPLE / "camera.yaml"),
                   "--layout", str(REPO / "marker_layouts" / "drick-aruco-centre.json"),
                   "--sink", spec, "--frames", "1", "--quiet"])
        out, err = capsys.readouterr()
        assert (rc, out) == (2, ""), (spec, err)
        assert err == f"drovisio run: --sink {spec}: {why}\n"
        assert err.count(spec) == 1


def test_open_sink_keeps_the_why_apart_from_the_spec():
    """``open_sink``'s refusal is the line, and carries the sink's own words apart (what a
    caller that names the sink itself, as the web tool's status may, says after it)."""
    with pytest.raises(SinkError) as e:
        open_sink("zenoh:domain=999&connect=tcp/127.0.0.1:7447")
    assert str(e.value) == ("--sink zenoh:domain=999&connect=tcp/127.0.0.1:7447: domain: '999': "
                            "use a ROS domain id, 0–232")
    assert e.value.why == "domain: '999': use a ROS domain id, 0–232"
