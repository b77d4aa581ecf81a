"""The Fleet page's API on a station: drones heard over Zenoh (a real sink on loopback), their
figures, thumbnails and web-tool links; the page itself; a web tool that is no station."""

from __future__ import annotations

import socket
import time

import cv2
import numpy as np
from fastapi.testclient import TestClient

from drovisio.pipeline import FrameOutput
from drovisio.raw_frame import RawFrame
from drovisio.ros.messages import RosMessages, namespace_for
from drovisio.sinks.zenoh import ZenohSink
from drovisio.tracking import TrackedBrick
from webtool.app import create_app
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"


def _free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = int(s.getsockname()[1])
    s.close()
    return port


def _output(k: int) -> FrameOutput:
    t = time.time()
    b = TrackedBrick(layout="drick-aruco-centre", instance=3, track=7, method="aruco",
                     rvec=np.zeros(3), tvec=np.array([0.1, 0.0, 1.5]),
                     covariance=np.eye(6) * 1e-6, t=t, t_measured=t, age=0.0, measured=True)
    return FrameOutput(source="cam", frame=k, seq=k, t=t, t_mono=time.monotonic(),
                       bricks=[b], target=b)


def test_a_station_lists_its_drones_with_target_thumbnail_and_link(tmp_path, until):
    port = _free_port()
    app = create_app(Settings(station_listen=[f"tcp/127.0.0.1:{port}"], data_dir=tmp_path))
    with TestClient(app, base_url=LOCAL) as c:
        assert c.get("/api/fleet/status").json()["drones"] == []
        ns, prefix = namespace_for("alpha")
        sink = ZenohSink(f"zenoh:connect=tcp/127.0.0.1:{port}&web=http://10.0.0.7:8080/",
                         RosMessages(None, None, (), namespace=ns, frame_prefix=prefix))
        try:
            frame = RawFrame(image=np.full((480, 640, 3), 90, np.uint8), index=0)
            k = 0
            st: dict = {}

            def heard() -> bool:
                # the status checked is the one that showed the drone live: a loaded machine
                # may let a second pass between two requests, and the drone is lost after one
                nonlocal k, st
                out = _output(k)
                sink.on_frame(frame, out)
                sink.send(out)
                k += 1
                st = c.get("/api/fleet/status").json()
                d = st["drones"]
                return (bool(d) and d[0]["has_image"] and bool(d[0]["info"])
                        and d[0]["state"] == "live")

            until(heard, pause=0.05)
            (d,) = st["drones"]
            assert st["listen"] == [f"tcp/127.0.0.1:{port}"] and st["error"] is None
            assert d["drone_id"] == "alpha" and d["state"] == "live" and d["bricks"] == 1
            assert d["target"]["layout"] == "drick-aruco-centre" and d["target"]["instance"] == 3
            assert d["target"]["tvec"] == [0.1, 0.0, 1.5]
            assert d["info"] == {"web": "http://10.0.0.7:8080/"}
            img = c.get("/api/fleet/drones/alpha/image.jpg")
            assert img.status_code == 200 and img.headers["content-type"] == "image/jpeg"
            pix = cv2.imdecode(np.frombuffer(img.content, np.uint8), cv2.IMREAD_COLOR)
            assert pix.shape == (240, 320, 3) and abs(float(pix.mean()) - 90) < 3
        finally:
            sink.close()
        # the sink's session ended: the drone is lost
        until(lambda: c.get("/api/fleet/status").json()["drones"][0]["state"] == "lost",
              pause=0.05)
        assert c.get("/api/fleet/drones/nobody/image.jpg").status_code == 404
        assert c.get("/api/fleet/drones/a%20b/image.jpg").status_code == 404
        page = c.get("/fleet")
        assert page.status_code == 200 and "Fleet" in page.text and "not-station" not in page.text
        assert 'href="/fleet"' in c.get("/").text


def test_a_web_tool_that_is_no_station_says_so(tmp_path):
    app = create_app(Settings(data_dir=tmp_path))
    with TestClient(app, base_url=LOCAL) as c:
        st = c.get("/api/fleet/status").json()
        assert st["drones"] == [] and st["listen"] == []
        page = c.get("/fleet")
        assert page.status_code == 200 and "not-station" in page.text
        assert 'href="/fleet"' not in c.get("/").text
