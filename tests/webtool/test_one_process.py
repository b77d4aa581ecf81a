"""One process on the drone: ``drovisio serve`` with a MAVLink sink feeds the flight
controller from the start, and the live page's "Make target" choice is what it receives."""

from __future__ import annotations

import time

from fastapi.testclient import TestClient

from drovisio.sinks.mavlink import mavutil2
from webtool.app import create_app
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"


def test_the_page_watches_the_pipeline_that_feeds_the_flight_controller(tmp_path):
    mavutil = mavutil2()
    fc = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=1, source_component=1)
    port = fc.port.getsockname()[1]
    settings = Settings(sinks=[f"mavlink:udpout:127.0.0.1:{port}"],
                        calibration_dir=tmp_path / "cal")
    app = create_app(settings)

    def received(n: int) -> list:
        """The next ``n`` LANDING_TARGET messages (counted, not timed: the bound only turns
        silence into a failure; a first run compiles the detectors' kernels meanwhile)."""
        out, end = [], time.monotonic() + 600
        while len(out) < n:
            assert time.monotonic() < end, f"the flight controller heard {len(out)} of {n}"
            m = fc.recv_match(type="LANDING_TARGET", blocking=True, timeout=0.5)
            if m is not None:
                out.append(m)
        return out

    try:
        with TestClient(app, base_url=LOCAL) as c:
            # no page asked for anything yet: the pipeline already feeds the sink
            first = received(10)
            assert app.state.live.pipeline is not None
            st = c.get("/api/live/status").json()
            sinks = {s["sink"]: s for s in st.get("sinks", [])}
            assert f"mavlink:udpout:127.0.0.1:{port}" in sinks
            # the page makes a brick the target: the autopilot receives that brick
            r = c.post("/api/live/target", json={"spec": "drick-aruco-centre:1"},
                       headers={"Origin": LOCAL})
            assert r.status_code == 200
            # what was sent before the change, and the one frame that may have chosen its
            # target just before it, are the old choice; every later message is the new one
            sink = next(s for s in app.state.live.pipeline.sinks
                        if s.name == f"mavlink:udpout:127.0.0.1:{port}")
            received(sink.delivery.sent + 1 - len(first))
            after = received(10)
            assert {m.target_num for m in after} == {1}
            st = c.get("/api/live/status").json()
            tb = st["target_brick"]
            assert tb is None or (tb["layout"], tb["instance"]) == ("drick-aruco-centre", 1)
            assert st["target"]["spec"] == "drick-aruco-centre:1"
    finally:
        fc.close()
