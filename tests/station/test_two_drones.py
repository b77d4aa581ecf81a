"""Two ``drovisio run`` drones and one station over Zenoh on loopback: both seen with their
targets, a ``kill -9`` seen as lost (the drone's liveliness token goes with its session: the
station's silence bound is made too long to be the reason), a restart seen again without
touching the station. The waits are bounds for failures only: a loaded machine, or a first
run compiling the detectors' kernels, is slow, not wrong."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from drovisio.station import Fleet, StationLink

pytest.importorskip("zenoh")


def _state(fleet: Fleet, drone: str) -> str | None:
    return next((d.state for d in fleet.status() if d.drone_id == drone), None)


def _target(fleet: Fleet, drone: str):
    return next((d.target for d in fleet.status() if d.drone_id == drone), None)


def test_station_sees_two_drones_a_kill_and_a_restart(tmp_path, drones, until):
    port = drones.free_port()
    fleet = Fleet(lost_after_s=3600.0)   # lost only when the session ends
    link = StationLink(fleet, listen=[f"tcp/127.0.0.1:{port}"])
    video = drones.rendered_video(tmp_path / "rendered.mp4")
    sample = drones.long_sample(tmp_path / "approach.mp4")
    one = drones.drone(port, "drone1", sample, "drick-aruco-pyramids.json",
                 web="&web=http://127.0.0.1:18080/")
    two = drones.drone(port, "drone2", video, "drick-aruco-centre.json")
    procs = [one, two]
    try:
        # both seen with a target (the first frames also load the detectors' kernels)
        seen: dict[str, dict] = {}

        def targets() -> bool:
            for d in fleet.status():
                if d.target is not None and d.state == "live":
                    seen.setdefault(d.drone_id, d.target)
            return len(seen) == 2

        until(targets, 600, say=lambda _: (fleet.status(), one.poll(), two.poll()))
        until(lambda: {d.drone_id: d.state for d in fleet.status()}
              == {"drone1": "live", "drone2": "live"}, 60)
        t1, t2 = seen["drone1"], seen["drone2"]
        assert t1["layout"] == "drick-aruco-pyramids" and t2["layout"] == "drick-aruco-centre"
        assert 0.3 < float(np.linalg.norm(t2["tvec"])) < 2.0    # metres from the camera
        info = {d.drone_id: d.info for d in fleet.status()}
        assert info == {"drone1": {"web": "http://127.0.0.1:18080/"}, "drone2": {}}
        # kill -9: no goodbye from the drone; its session's end withdraws its token
        os.kill(one.pid, signal.SIGKILL)
        one.wait(60)
        until(lambda: _state(fleet, "drone1") == "lost", 60, say=lambda _: fleet.status())
        assert _state(fleet, "drone2") == "live"
        # a restart is seen again by the same station
        one = drones.drone(port, "drone1", sample, "drick-aruco-pyramids.json")
        procs.append(one)
        until(lambda: _state(fleet, "drone1") == "live", 600)
        assert link.dropped == 0
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(60)
        link.close()
