"""A replay of a simulated run plays in the live page: the panel loads a short
recording, plays it (the time and the state of the machine move on), and the server-side
playback moves the drone and drives the replay's 3D view."""

from __future__ import annotations

import time

import pytest

from drovisio.mission.record import write_recording
from drovisio.mission.scenario import load_scenario, shipped_scenario
from drovisio.mission.sim import SimParams, simulate
from webtool.settings import Settings

pytestmark = pytest.mark.browser


def _text(page, el_id: str) -> str:
    return page.locator("#" + el_id).inner_text().strip()


def test_replay_of_a_simulated_run_plays_in_the_live_page(page, live_server_factory, tmp_path):
    scn = load_scenario(shipped_scenario()).subset(["b1"])
    write_recording(simulate(scn, params=SimParams(seed=2)), tmp_path / "one-brick", every=2)
    base = live_server_factory(Settings(replay_dir=tmp_path))
    page.set_default_timeout(120_000)
    page.goto(base + "/live")
    page.wait_for_function(
        "[...document.querySelectorAll('#replay-run option')].some(o => o.value === 'one-brick')")
    page.select_option("#replay-run", "one-brick")
    page.click("#replay-load")
    page.wait_for_function("document.getElementById('replay-state').textContent === 'TAKE_OFF'")
    assert _text(page, "replay-time") == "0.0 s"
    assert _text(page, "replay-placed") == "0 of 1"
    p0 = page.request.get(base + "/api/replay/state").json()["drone"]["position"]

    page.select_option("#replay-speed", "4")
    page.wait_for_function("document.getElementById('replay-msg').textContent === ''")
    page.click("#replay-play")
    # the clock advances and the machine leaves TAKE_OFF (later states, in plain words)
    page.wait_for_function("parseFloat(document.getElementById('replay-time').textContent) > 5")
    page.wait_for_function("!['TAKE_OFF', '–'].includes("
                           "document.getElementById('replay-state').textContent)")
    seen = {_text(page, "replay-state")}
    assert page.locator("#replay-events li").count() >= 2
    assert any("→" in x for x in page.locator("#replay-events li").all_inner_texts())
    st = page.request.get(base + "/api/replay/state").json()
    assert st["t"] > 5 and st["drone"]["position"] != p0
    # the drone keeps moving while playing (a slow machine may have played it to its end);
    # the server's own state says which, the bound is for failures only
    deadline = time.monotonic() + 120
    while True:
        st2 = page.request.get(base + "/api/replay/state").json()
        if st2["state"] == "DONE" or st2["t"] > st["t"]:
            break
        assert time.monotonic() < deadline, (st, st2)
        time.sleep(0.1)
    assert st2["t"] >= st["t"]
    if st2["state"] != "DONE":
        assert st2["drone"]["position"] != st["drone"]["position"]
    # to the end: the brick is placed and the run is DONE
    page.wait_for_function("document.getElementById('replay-state').textContent === 'DONE'",
                           timeout=120_000)
    seen.add(_text(page, "replay-state"))
    assert _text(page, "replay-placed") == "1 of 1"
    assert len(seen) >= 2
    # the replay's 3D view: viser's client in the iframe, connected, updated by the playback
    page.frame_locator("#replay-frame").locator("canvas").first.wait_for(state="attached")
    deadline = time.monotonic() + 120   # a bound for failures only
    sc = {}
    while time.monotonic() < deadline:
        sc = page.request.get(base + "/api/replay/scene").json()
        if sc.get("clients", 0) >= 1 and sc.get("updates", 0) >= 5:
            break
        time.sleep(0.3)
    assert sc.get("clients", 0) >= 1 and sc.get("updates", 0) >= 5, sc
    # seeking back with the slider's API and pausing
    st = page.request.post(base + "/api/replay/seek", data={"t": 1.0}).json()
    assert st["state"] == "TAKE_OFF"
    page.wait_for_function("document.getElementById('replay-state').textContent === 'TAKE_OFF'")
    page.wait_for_timeout(1000)  # let the 3D view draw the seek, for the screenshot
    page.screenshot(path=str(tmp_path / "replay.png"), full_page=True)


def test_without_recordings_the_panel_says_how_to_make_one(page, live_server_factory, tmp_path):
    base = live_server_factory(Settings(replay_dir=tmp_path))
    page.goto(base + "/live")
    page.wait_for_function(
        "document.getElementById('replay-msg').textContent.startsWith('No recordings yet')")
    assert "drovisio mission simulate" in _text(page, "replay-msg")
    assert page.locator("#replay-load").is_disabled()
