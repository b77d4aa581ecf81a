"""The Fleet page in headless Chromium: ``drovisio station`` and two ``drovisio run`` drones
(the sample video and rendered frames) over Zenoh on loopback; both listed live with their
targets; ``kill -9`` of one shows it lost; its restart brings it back, the station untouched.
The waits are bounds for failures only (a loaded machine, or a first run compiling the
detectors' kernels, is slow, not wrong)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import urllib.request

import pytest

pytest.importorskip("zenoh")
pytestmark = pytest.mark.browser


def _up(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=2) as r:
            return r.status == 200
    except OSError:
        return False


def _row(page, drone_id: str):
    return page.locator(f'#fleet-rows tr[data-drone="{drone_id}"]')


def test_fleet_page_shows_two_drones_a_kill_and_a_restart(page, tmp_path, drones, until):
    zport, wport = drones.free_port(), drones.free_port()
    log = (tmp_path / "station.log").open("w")
    station = subprocess.Popen(
        [sys.executable, "-m", "drovisio", "station", "--listen", f"tcp/127.0.0.1:{zport}",
         "--port", str(wport), "--data", str(tmp_path / "data")],
        stdout=log, stderr=subprocess.STDOUT, cwd=drones.REPO)
    base = f"http://127.0.0.1:{wport}"
    procs = [station]
    try:
        until(lambda: _up(base + "/api/health"), 300,
              say=lambda _: (tmp_path / "station.log").read_text())
        video = drones.rendered_video(tmp_path / "rendered.mp4")
        sample = drones.long_sample(tmp_path / "approach.mp4")
        one = drones.drone(zport, "drone1", sample, "drick-aruco-pyramids.json",
                    web="&web=http://127.0.0.1:18080/")
        two = drones.drone(zport, "drone2", video, "drick-aruco-centre.json")
        procs += [one, two]
        page.goto(base + "/fleet")
        assert page.locator("h1").inner_text().strip() == "Fleet"
        # both live, each with its target named in its row
        for d, layout in (("drone1", "drick-aruco-pyramids"), ("drone2", "drick-aruco-centre")):
            page.wait_for_function(
                """([d, layout]) => { const r = document.querySelector(`tr[data-drone="${d}"]`);
                     return r && r.className === "live"
                       && r.querySelector("td.target").textContent.startsWith(layout); }""",
                arg=[d, layout], timeout=600_000)
        assert _row(page, "drone1").locator("a").get_attribute("href") == \
            "http://127.0.0.1:18080/"
        # kill -9: the page says lost (why — the session's end — is checked without a browser
        # in test_two_drones)
        os.kill(one.pid, signal.SIGKILL)
        one.wait(60)
        page.wait_for_function(
            """() => { const r = document.querySelector('tr[data-drone="drone1"]');
                       return r && r.className === "lost"; }""", timeout=60_000)
        assert _row(page, "drone2").get_attribute("class") == "live"
        # restart: seen again by the same station
        procs.append(drones.drone(zport, "drone1", sample, "drick-aruco-pyramids.json"))
        page.wait_for_function(
            """() => { const r = document.querySelector('tr[data-drone="drone1"]');
                       return r && r.className === "live"; }""", timeout=600_000)
        assert station.poll() is None
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(60)
        log.close()
