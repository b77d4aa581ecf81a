"""The live page's flight-controller box: the same autopilot check, over the sink's own link."""

from __future__ import annotations

import time

from fastapi.testclient import TestClient

from webtool.app import create_app
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"


def test_live_status_carries_the_autopilot_check(vehicle, ardupilot_ok, tmp_path):
    v = vehicle(params=dict(ardupilot_ok, PLND_ORIENT=0))
    app = create_app(Settings(sinks=[f"mavlink:udpout:127.0.0.1:{v.port}"],
                              calibration_dir=tmp_path / "cal"))
    with TestClient(app, base_url=LOCAL) as c:
        end, sink = time.monotonic() + 300, {}    # a bound for failures only (a loaded machine)
        while time.monotonic() < end:
            st = c.get("/api/live/status").json()
            sink = next(s for s in st["sinks"] if s["sink"].startswith("mavlink:"))
            got = {f["item"]: f for f in sink["check"]}
            if got.get("PLND_ORIENT", {}).get("status") == "wrong" and \
                    got.get("PLND_LAG", {}).get("status") in ("ok", "wrong") and \
                    got.get("detection rate", {}).get("status", "unknown") != "unknown":
                break
            time.sleep(0.2)
        assert sink["vehicle"] == {"system": 1, "component": 1, "autopilot": "ArduPilot"}
        assert sink["note"] is None and sink["attitude"] is True
        got = {f["item"]: f for f in sink["check"]}
        assert got["PLND_ORIENT"]["status"] == "wrong"
        assert "0 → set 25" in got["PLND_ORIENT"]["text"]
        assert got["PLND_TYPE"]["status"] == "ok" and got["ATTITUDE"]["status"] == "ok"
        # the sample session shows the brick: the sink measured its own latency and rate (their
        # values depend on this machine's load: only that they were measured)
        assert got["detection rate"]["status"] != "unknown" and "Hz" in got["detection rate"][
            "text"]
        assert got["latency"]["status"] == "ok" and "PLND_LAG 0." in got["latency"]["text"]
