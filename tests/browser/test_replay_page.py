"""A replay of a simulated run plays in the live page: the panel loads a short
recording, plays it (the time and the state of the machine move on), and the server-side
playback moves the drone and drives the replay's 3D view."""

from __future__ import annotations

import pytest

from drovisio.mission.record import write_recording
from drovisio.mission.scenario import load_scenario, shipped_scenario
from drovisio.mission.sim import SimParams, simulate
from webtool.settings import Settings

pytestmark = pytest.mark.browser


def _text(page, el_id: str) -> str:
    return page.locator("#" + el_id).inner_text().strip()


def test_replay_of_a_simulated_run_plays_in_the_live_page(page, live_server_factory, tmp_path,
                                                          until):
    scn = load_scenario(shipped_scenario()).subset(["b1"])
    write_recording(simulate(scn, params=SimParams(seed=2)), tmp_path / "one-brick", every=2)
    base = live_server_factory(Settings(replay_dir=tmp_path))
    page.set_default_timeout(120_000)

    def scene() -> dict:
        return page.request.get(base + "/api/replay/scene").json()

    page.goto(base + "/live")
    page.wait_for_function(
        "[...document.querySelectorAll('#replay-run option')].some(o => o.value === 'one-brick')")
    page.select_option("#replay-run", "one-brick")
    page.click("#replay-load")
    page.wait_for_function("document.getElementById('replay-state').textContent === 'TAKE_OFF'")
    assert _text(page, "replay-time") == "0.0 s"
    assert _text(page, "replay-placed") == "0 of 1"
    seen = {_text(page, "replay-state")}
    p0 = page.request.get(base + "/api/replay/state").json()["drone"]["position"]
    # the replay's 3D view: viser's client in the iframe, connected before the run plays
    page.frame_locator("#replay-frame").locator("canvas").first.wait_for(state="attached")
    until(scene, 120, done=lambda s: s.get("clients", 0) >= 1, pause=0.1)

    page.select_option("#replay-speed", "4")
    page.wait_for_function("document.getElementById('replay-msg').textContent === ''")
    page.click("#replay-play")
    # the clock advances and the machine leaves TAKE_OFF (later states, in plain words)
    page.wait_for_function("parseFloat(document.getElementById('replay-time').textContent) > 5")
    page.wait_for_function("!['TAKE_OFF', '–'].includes("
                           "document.getElementById('replay-state').textContent)")
    seen.add(_text(page, "replay-state"))
    assert page.locator("#replay-events li").count() >= 2
    assert any("→" in x for x in page.locator("#replay-events li").all_inner_texts())
    st = page.request.get(base + "/api/replay/state").json()
    assert st["t"] > 5 and st["drone"]["position"] != p0
    # the drone keeps moving while playing (a slow machine may have played it to its end):
    # the server's own state says which
    st2 = until(lambda: page.request.get(base + "/api/replay/state").json(), 120,
                done=lambda s: s["state"] == "DONE" or (
                    s["t"] > st["t"] and s["drone"]["position"] != st["drone"]["position"]),
                pause=0.1)
    assert st2["t"] >= st["t"]
    # to the end: the brick is placed and the run is DONE
    page.wait_for_function("document.getElementById('replay-state').textContent === 'DONE'",
                           timeout=120_000)
    seen.add(_text(page, "replay-state"))
    assert _text(page, "replay-placed") == "1 of 1"
    assert len(seen) >= 2
    # the 3D view was updated by the playback
    sc = until(scene, 120, pause=0.1,
               done=lambda s: s.get("clients", 0) >= 1 and s.get("updates", 0) >= 5)
    # seeking back with the slider's API and pausing
    st = page.request.post(base + "/api/replay/seek", data={"t": 1.0}).json()
    assert st["state"] == "TAKE_OFF"
    page.wait_for_function("document.getElementById('replay-state').textContent === 'TAKE_OFF'")
    # the seek drawn, for the screenshot
    until(scene, 120, done=lambda s: s["updates"] > sc["updates"], pause=0.1)
    page.screenshot(path=str(tmp_path / "replay.png"), full_page=True)


def test_without_recordings_the_panel_says_how_to_make_one(page, live_server_factory, tmp_path):
    base = live_server_factory(Settings(replay_dir=tmp_path))
    page.goto(base + "/live")
    page.wait_for_function(
        "document.getElementById('replay-msg').textContent.startsWith('No recordings yet')")
    assert "drovisio mission simulate" in _text(page, "replay-msg")
    assert page.locator("#replay-load").is_disabled()
