"""The calibration API (webtool.routes.calibration + webtool.calibration.service) through
FastAPI's TestClient: live auto-capture and persistence, a camera that disappears, manual capture,
delete, uploads with bad files, solve / result / downloads / use, resume after a restart, token
access. Frames come from small scripted sources (the sample session's views), so each test takes
a second or two."""

from __future__ import annotations

import asyncio
import io
import itertools
import json
import re
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from drovisio.camera_file import load_camera
from drovisio.sources import PlaybackReader, RawFrame
from webtool.app import create_app
from webtool.calibration.service import CalibrationService
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"  # the Host a browser on this machine sends

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_sessions" / "calibration"
TRUE_CAMERA = REPO / "sample_sessions" / "camera.yaml"
API = "/api/calibration"


def _img(i: int) -> np.ndarray:
    return cv2.imread(str(SAMPLE / f"view_{i:02d}.jpg"))


def _jpeg_bytes(i: int) -> bytes:
    return (SAMPLE / f"view_{i:02d}.jpg").read_bytes()


BLANK = np.full((480, 640, 3), 128, np.uint8)
# sample views at least 60 px apart (mean corner distance): the novelty gate keeps each one
NOVEL = [0, 4, 5, 7, 8, 12, 14, 16]


class ScriptedSource:
    """Frames from a list (each view twice, so that the stillness gate passes), then nothing
    (a lost camera) — or the last frame forever with ``hold=True``."""

    label = "scripted test camera"
    finite = False

    def __init__(self, frames: list[np.ndarray], hold: bool = False) -> None:
        self.frames = list(frames)
        self.hold = hold
        self.i = 0

    def open(self) -> None:
        pass

    def read(self):
        time.sleep(0.01)
        if self.i < len(self.frames):
            self.i += 1
            return RawFrame(self.frames[self.i - 1], self.i - 1)
        return RawFrame(self.frames[-1], self.i) if (self.hold and self.frames) else None

    def close(self) -> None:
        pass


def still(views) -> list[np.ndarray]:
    return [f for i in views for f in (_img(i), _img(i))]


@pytest.fixture
def make_client(tmp_path):
    made: list[CalibrationService] = []

    def make(factory=None, folder: Path | None = None, **kw) -> TestClient:
        settings = Settings(calibration_dir=folder or tmp_path / "cal", **kw)
        app = create_app(settings)
        if factory is not None:
            app.state.calibration = CalibrationService(settings, source_factory=factory)
            made.append(app.state.calibration)
        client = TestClient(app, base_url=LOCAL)
        if factory is None:
            client.get(f"{API}/state")  # creates the service from the settings
            made.append(app.state.calibration)
        return client

    yield make
    for svc in made:
        svc.close()


def no_camera():
    return ScriptedSource([])


@pytest.fixture
def wait_state(until):
    """``wait_state(client, pred, timeout=300)``: the first state ``pred`` holds for; the
    bound only turns a hang into a failure (a loaded machine captures and solves slowly, not
    wrongly)."""
    def wait(client: TestClient, pred, timeout: float = 300.0) -> dict:
        return until(lambda: client.get(f"{API}/state").json(), timeout, done=pred,
                     pause=0.05, say=lambda s: f"camera={s['camera']} views={len(s['views'])} "
                                               f"feedback={s['feedback']}")

    return wait


def upload(client: TestClient, files: list[tuple[str, bytes]]) -> dict:
    r = client.post(f"{API}/upload",
                    files=[("files", (name, io.BytesIO(data), "application/octet-stream"))
                           for name, data in files])
    assert r.status_code == 200, r.text
    return r.json()


def session_dir(client: TestClient) -> Path:
    return Path(client.get(f"{API}/state").json()["session"]["folder"])


# ---------------------------------------------------------------------------------- tests
def test_page_and_static_files(make_client):
    c = make_client(no_camera)
    html = c.get("/calibration").text
    for needle in ('id="live"', 'id="heatmap"', 'id="hint-outline"', 'id="auto"',
                   'id="capture"', 'id="solve"', 'id="views"', 'webkitdirectory',
                   "/static/calibration.js"):
        assert needle in html, needle
    assert c.get("/static/calibration.js").status_code == 200
    assert c.get("/static/calibration.css").status_code == 200
    s = c.get(f"{API}/state").json()
    assert s["views"] == [] and s["session"]["board"] == "chessboard:9x6"
    assert s["progress"]["next"].startswith("Hold the printed chessboard")
    assert (session_dir(c) / "session.json").is_file()


def test_live_auto_capture_saves_each_view_at_once(make_client, wait_state):
    c = make_client(lambda: ScriptedSource(still(NOVEL[:5]), hold=True))
    s = wait_state(c, lambda s: len(s["views"]) == 5)
    folder = Path(s["session"]["folder"])
    saved = json.loads((folder / "session.json").read_text())
    assert len(saved["session"]["views"]) == 5
    names = [v["name"] for v in s["views"]]
    assert all((folder / "images" / n).is_file() for n in names)
    assert not list((folder / "images").glob(".*"))  # no temporary files left behind
    assert s["coverage"]["image_covered_fraction"] > 0
    assert s["suggestion"]["sentence"].startswith("Hold the board")
    assert len(s["suggestion"]["outline_px"]) >= 4
    r = c.get(f"{API}/frame.jpg")
    assert r.status_code == 200 and r.content[:2] == b"\xff\xd8"
    assert int(r.headers["x-frame-seq"]) > 0
    r = c.get(s["views"][0]["thumb"])
    assert r.status_code == 200 and r.content[:2] == b"\xff\xd8"


def test_pages_waiting_for_a_frame_hold_no_worker_thread(make_client, wait_state):
    """Forty pages each waiting (a second) for a frame newer than any: with one worker
    thread, a route that needs it still answers (a wait held a thread each, before)."""
    import anyio
    import httpx

    c = make_client(lambda: ScriptedSource(still([0]), hold=True))
    wait_state(c, lambda s: s["camera"]["state"] == "ok")

    async def main() -> None:
        anyio.to_thread.current_default_thread_limiter().total_tokens = 1  # this loop's
        transport = httpx.ASGITransport(app=c.app)
        async with httpx.AsyncClient(transport=transport, base_url=LOCAL) as client:
            waiting = [asyncio.create_task(client.get(f"{API}/frame.jpg?after=10000000"))
                       for _ in range(40)]
            await asyncio.sleep(0)
            r = await asyncio.wait_for(client.get(f"{API}/state"), 60)  # failure, not timing
            assert r.status_code == 200 and r.json()["camera"]["state"] == "ok"
            frames = await asyncio.wait_for(asyncio.gather(*waiting), 60)
        assert all(f.status_code == 200 and f.content[:2] == b"\xff\xd8" for f in frames)

    asyncio.run(main())


def test_sample_playback_auto_captures(make_client, wait_state):
    c = make_client(sample_seconds_per_view=0.3)
    s = wait_state(c, lambda s: len(s["views"]) >= 3)
    assert s["session"]["sample"] is True and s["camera"]["state"] == "ok"


def test_sample_playback_still_and_moving_frames():
    files = sorted(SAMPLE.glob("view_*.jpg"))[:2]
    src = PlaybackReader(files, seconds_per_view=0.4, fps=40)
    frames = [src.read().image for _ in range(24)]  # ~0.6 s: view 0 still, then the move to view 1
    from drovisio.calibration import parse_board
    from drovisio.calibration.board import detect
    board = parse_board("chessboard:9x6", 0.025)
    dets = [detect(f, board) for f in frames]
    assert dets[0] is not None and dets[1] is not None
    assert np.abs(dets[0].corners - dets[1].corners).max() < 1.5  # still: jitter only
    assert any(not np.array_equal(a, b) for a, b in itertools.pairwise(frames))


def test_camera_lost_mid_session_keeps_views_and_recovers(make_client, wait_state):
    back = threading.Event()
    calls = {"n": 0}

    def factory():
        calls["n"] += 1
        if calls["n"] == 1:
            return ScriptedSource(still(NOVEL[:3]))  # then the camera "is unplugged"
        if not back.is_set():
            raise OSError("/dev/video0: no such device")
        return ScriptedSource(still(NOVEL[3:4]), hold=True)

    c = make_client(factory)
    s = wait_state(c, lambda s: s["camera"]["state"] == "disconnected")
    assert "Camera disconnected — retrying" in s["camera"]["message"]
    assert "The 3 views captured so far are saved." in s["camera"]["message"]
    assert len(s["views"]) == 3
    assert "disconnected" in s["progress"]["next"]
    r = c.get(f"{API}/frame.jpg")
    assert r.status_code == 503 and "disconnected" in r.json()["detail"]
    r = c.post(f"{API}/capture")
    assert r.status_code == 409 and "No picture from the camera" in r.json()["detail"]
    folder = Path(s["session"]["folder"])
    assert len(json.loads((folder / "session.json").read_text())["session"]["views"]) == 3
    back.set()
    s = wait_state(c, lambda s: s["camera"]["state"] == "ok" and len(s["views"]) == 4)
    assert [v["id"] for v in s["views"]] == [0, 1, 2, 3]


def test_manual_capture_with_auto_off(make_client, wait_state):
    frames = {"f": _img(0)}

    class Live:
        label = "test"
        finite = False

        def open(self):
            pass

        def read(self):
            time.sleep(0.01)
            return RawFrame(frames["f"], 0)

        def close(self):
            pass

    c = make_client(Live)
    assert c.post(f"{API}/auto", json={"on": False}).json() == {"auto_capture": False}
    s = wait_state(c, lambda s: s["feedback"]["detected"])
    assert "Press Capture" in s["feedback"]["message"] and s["views"] == []
    r = c.post(f"{API}/capture")
    assert r.status_code == 200 and r.json()["view_id"] == 0
    r = c.post(f"{API}/capture")
    assert r.status_code == 409 and "already kept (view #0)" in r.json()["detail"]
    frames["f"] = BLANK
    wait_state(c, lambda s: not s["feedback"]["detected"])
    r = c.post(f"{API}/capture")
    assert r.status_code == 422 and "No board in view" in r.json()["detail"]
    s = c.get(f"{API}/state").json()
    assert len(s["views"]) == 1 and s["auto_capture"] is False
    saved = json.loads((Path(s["session"]["folder"]) / "session.json").read_text())
    assert saved["auto_capture"] is False


def test_capture_while_a_busy_machine_is_slow_over_the_next_frame(make_client, wait_state):
    """The camera keeps giving frames, the machine takes long over each (a busy or a small
    computer): Capture keeps the latest one (it was refused as "no picture from the camera
    right now" once a frame had taken over 3 s)."""

    class Live:
        label = "test"
        finite = False

        def open(self):
            pass

        def read(self):
            time.sleep(0.01)
            return RawFrame(_img(0), 0)

        def close(self):
            pass

    c = make_client(Live)
    assert c.post(f"{API}/auto", json={"on": False}).status_code == 200
    wait_state(c, lambda s: s["feedback"]["detected"])
    feed = c.app.state.calibration._feed
    busy, done = threading.Event(), threading.Event()
    handle = feed._on_frame

    def slow(image):
        busy.set()
        done.wait(60)
        handle(image)

    feed._on_frame = slow
    try:
        assert busy.wait(60)         # the worker is over the next frame ...
        time.sleep(3.5)              # ... for longer than a camera may give nothing
        r = c.post(f"{API}/capture")
        assert r.status_code == 200 and r.json()["view_id"] == 0, r.text
    finally:
        done.set()


def test_delete_view_moves_its_image_aside(make_client):
    c = make_client(no_camera)
    upload(c, [(f"v{i}.jpg", _jpeg_bytes(i)) for i in range(3)])
    s = c.get(f"{API}/state").json()
    vid, name = s["views"][1]["id"], s["views"][1]["name"]
    r = c.delete(f"{API}/views/{vid}")
    assert r.status_code == 200 and r.json()["views"] == 2
    folder = Path(s["session"]["folder"])
    assert not (folder / "images" / name).exists()
    assert (folder / "deleted" / name).is_file()
    assert c.delete(f"{API}/views/{vid}").status_code == 404
    assert c.get(f"{API}/views/{vid}/thumb.jpg").status_code == 404


def test_a_name_deleted_twice_keeps_both_images(make_client):
    c = make_client(no_camera)
    folder = session_dir(c)
    sent = []
    for i in (3, 4):
        sent.append(_jpeg_bytes(i))
        upload(c, [("same.jpg", sent[-1])])
        vid = c.get(f"{API}/state").json()["views"][0]["id"]
        assert c.delete(f"{API}/views/{vid}").status_code == 200
    kept = sorted((folder / "deleted").iterdir())
    assert [p.name for p in kept] == ["upload-same-2.jpg", "upload-same.jpg"]
    assert {p.read_bytes() for p in kept} == set(sent)


def test_uploads_of_one_name_at_once_each_keep_their_own_image(make_client):
    # the first upload is held between its detection and its keeping while a second one of
    # the same name is kept whole: each view must still point at its own picture
    c = make_client(no_camera)
    svc = c.app.state.calibration
    sess = svc.session
    real, held, go = sess.evaluate, threading.Event(), threading.Event()

    def evaluate(img, name="", still=False):
        fr = real(img, name, still=still)
        if not held.is_set():
            held.set()
            assert go.wait(60)
        return fr

    sess.evaluate = evaluate
    a, b = _jpeg_bytes(5), _jpeg_bytes(6)
    first = threading.Thread(target=svc.upload, args=([("same.jpg", io.BytesIO(a))],))
    first.start()
    assert held.wait(60)
    svc.upload([("same.jpg", io.BytesIO(b))])
    go.set()
    first.join(60)
    views = c.get(f"{API}/state").json()["views"]
    folder = session_dir(c)
    assert len(views) == 2 and len({v["name"] for v in views}) == 2
    on_disk = {(folder / "images" / v["name"]).read_bytes() for v in views}
    assert on_disk == {a, b}


def test_upload_gives_a_message_per_file(make_client):
    c = make_client(no_camera)  # no camera at all: uploads still work
    good = [(f"folder/view_{i:02d}.jpg", _jpeg_bytes(i)) for i in range(4)]
    corrupt = ("folder/cut.jpg", _jpeg_bytes(5)[:4000])
    _, buf = cv2.imencode(".png", BLANK)
    blank = ("folder/blank.png", buf.tobytes())
    _, buf = cv2.imencode(".jpg", cv2.resize(_img(6), (320, 240)))
    small = ("folder/small.jpg", buf.tobytes())
    notes = ("folder/notes.txt", b"hello")
    rep = upload(c, good + [corrupt, blank, small, notes])
    msgs = {f["file"]: f for f in rep["files"]}
    assert rep["kept"] == 4 and rep["summary"].startswith("4 of 7 images kept")
    assert all(msgs[n]["ok"] for n, _ in good)
    assert "corrupt JPEG" in msgs["folder/cut.jpg"]["message"]
    assert "no board found" in msgs["folder/blank.png"]["message"]
    assert "wrong size: 320×240" in msgs["folder/small.jpg"]["message"]
    assert "640×480" in msgs["folder/small.jpg"]["message"]
    assert msgs["folder/notes.txt"]["message"] == "skipped: not an image file"
    s = c.get(f"{API}/state").json()
    assert [v["origin"] for v in s["views"]] == ["upload"] * 4
    again = upload(c, good[:1])  # the same photo twice is not counted twice
    assert again["kept"] == 0 and "already in this session" in again["files"][0]["message"]
    assert all((Path(s["session"]["folder"]) / "images" / v["name"]).is_file()
               for v in s["views"])


def test_upload_of_a_folder_without_the_board(make_client):
    c = make_client(no_camera)
    _, buf = cv2.imencode(".jpg", BLANK)
    rep = upload(c, [("a.jpg", buf.tobytes()), ("b.jpg", buf.tobytes())])
    assert rep["kept"] == 0
    assert "No chessboard:9x6 board was found in any of them" in rep["summary"]
    # a session for the wrong board size says which board is in the pictures
    r = c.post(f"{API}/session", json={"board": "chessboard:7x6", "square_m": 0.025})
    assert r.status_code == 200 and r.json()["board"] == "chessboard:7x6"
    rep = upload(c, [("view.jpg", _jpeg_bytes(0))])
    assert rep["kept"] == 0 and "9×6 inner corners is visible in view.jpg" in rep["summary"]


def test_new_session_with_a_bad_board_is_refused(make_client):
    c = make_client(no_camera)
    r = c.post(f"{API}/session", json={"board": "chessboard:2x6", "square_m": 0.025})
    assert r.status_code == 422 and "at least 3x3" in r.json()["detail"]
    r = c.post(f"{API}/session", json={"board": "chessboard:9x6", "square_m": 25})
    assert r.status_code == 422 and "metres" in r.json()["detail"]


def test_nothing_to_solve_yet(make_client):
    c = make_client(no_camera)
    r = c.post(f"{API}/solve")
    assert r.status_code == 409 and "at least 4 views" in r.json()["detail"]
    assert c.get(f"{API}/result").status_code == 404
    assert c.get(f"{API}/camera-file").status_code == 404
    assert c.get(f"{API}/uncertainty.png").status_code == 404
    assert c.post(f"{API}/use").status_code == 409


def test_solve_result_downloads_and_use(make_client, tmp_path, wait_state):
    c = make_client(no_camera)
    upload(c, [(f"view_{i:02d}.jpg", _jpeg_bytes(i)) for i in range(10)])
    r = c.post(f"{API}/solve")
    assert r.status_code == 202
    s = wait_state(c, lambda s: s["solve"]["has_result"] and s["solve"]["current"]
                   and not s["solve"]["solving"])
    assert s["solve"]["show_result"] is True
    assert s["progress"]["p95_px"] is not None
    assert all(v["rms_px"] is not None for v in s["views"])
    rep = c.get(f"{API}/result").json()
    assert set(rep["std"]) == {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"}
    assert rep["rms_px"] < 0.5 and "root mean square" in rep["rms_definition"]
    assert isinstance(rep["verdict"]["ok"], bool) and rep["current"] is True
    png = c.get(f"{API}/uncertainty.png")
    assert png.status_code == 200 and png.content[:4] == b"\x89PNG"
    true_fx = load_camera(TRUE_CAMERA).fx
    for fmt, suffix in (("opencv", ".yaml"), ("ros", ".ros.yaml"), ("json", ".json")):
        r = c.get(f"{API}/camera-file", params={"format": fmt})
        assert r.status_code == 200, fmt
        assert r.headers["content-disposition"].startswith("attachment;")
        assert r.headers["content-disposition"].rstrip('"').endswith(suffix)
        p = tmp_path / f"cam{suffix}"
        p.write_bytes(r.content)
        assert abs(load_camera(p).fx - true_fx) / true_fx < 0.01, fmt
    assert c.get(f"{API}/camera-file", params={"format": "xml2"}).status_code == 422
    r = c.post(f"{API}/use")
    assert r.status_code == 200
    used = Path(r.json()["camera_file"])
    assert used.is_file() and c.app.state.settings.camera == used
    assert abs(load_camera(used).fx - true_fx) / true_fx < 0.01
    s = c.get(f"{API}/state").json()
    assert s["in_use"] == {"camera_file": str(used), "this_session": True}
    assert str(used) in c.get("/").text  # the start page shows the camera now in use
    # a restart of the web tool keeps it; a camera given on the command line wins; a
    # choice whose file is gone is ignored
    again = create_app(Settings(calibration_dir=tmp_path / "cal"))
    assert again.state.settings.camera == used
    given = tmp_path / "given.yaml"
    given.write_bytes(used.read_bytes())
    assert create_app(Settings(calibration_dir=tmp_path / "cal", camera=given)
                      ).state.settings.camera == given
    used.unlink()
    assert create_app(Settings(calibration_dir=tmp_path / "cal")).state.settings.camera is None


def test_resume_after_restart_and_recover_orphans(make_client, tmp_path):
    folder = tmp_path / "cal"
    c1 = make_client(no_camera, folder=folder)
    upload(c1, [(f"view_{i:02d}.jpg", _jpeg_bytes(i)) for i in range(5)])
    s1 = c1.get(f"{API}/state").json()
    c1.app.state.calibration.close()
    # a crash right after an image was written, before session.json named it
    (Path(s1["session"]["folder"]) / "images" / "capture-0042.png").write_bytes(
        cv2.imencode(".png", _img(7))[1].tobytes())
    c2 = make_client(no_camera, folder=folder)
    s2 = c2.get(f"{API}/state").json()
    assert s2["session"]["id"] == s1["session"]["id"]
    assert [v["name"] for v in s2["views"]][:5] == [v["name"] for v in s1["views"]]
    assert "capture-0042.png" in [v["name"] for v in s2["views"]]
    # another source does not mix its views into this session
    c3 = make_client(no_camera, folder=folder, source="/dev/video9")
    s3 = c3.get(f"{API}/state").json()
    assert s3["session"]["id"] != s1["session"]["id"] and s3["views"] == []


def test_writes_work_with_the_token(make_client):
    c = make_client(no_camera, host="0.0.0.0", token="tok-123")
    assert c.get(f"{API}/state").status_code == 401
    assert c.post(f"{API}/auto", json={"on": False}).status_code == 401
    assert c.get("/calibration?token=tok-123").status_code == 200  # sets the cookie
    assert c.post(f"{API}/auto", json={"on": False}).status_code == 200
    assert c.get(f"{API}/state").json()["auto_capture"] is False


def test_lens_model_choice_solves_again_and_says_why(make_client, wait_state):
    c = make_client(no_camera)
    upload(c, [(f"view_{i:02d}.jpg", _jpeg_bytes(i)) for i in range(10)])
    assert c.post(f"{API}/solve").status_code == 202
    s = wait_state(c, lambda s: s["solve"]["has_result"] and s["solve"]["current"])
    assert s["lens"] == {"model": "plumb_bob", "solved_with": "plumb_bob", "choice": None}
    r = c.post(f"{API}/lens", json={"model": "auto"})
    assert r.status_code == 200 and r.json() == {"lens_model": "auto"}
    s = wait_state(c, lambda s: s["solve"]["current"] and s["lens"]["choice"] is not None)
    assert s["lens"]["model"] == "auto" and s["lens"]["choice"]["chosen"] == "plumb_bob"
    assert "held-out RMS" in s["lens"]["choice"]["reason"]
    rep = c.get(f"{API}/result").json()
    assert rep["camera"]["model"] == "plumb_bob" and rep["model_choice"]["chosen"] == "plumb_bob"
    # the page's solves say how flat the board was (the shipped views: a rendered flat board)
    flat = rep["board_flatness"]
    assert flat["computed"] and not flat["matters"] and "board" in flat["summary"]
    c.post(f"{API}/lens", json={"model": "fisheye"})
    s = wait_state(c, lambda s: s["solve"]["current"] and s["lens"]["solved_with"] == "fisheye")
    rep = c.get(f"{API}/result").json()
    assert set(rep["std"]) == {"fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"}
    assert len(rep["camera"]["dist"]) == 4
    c.post(f"{API}/lens", json={"model": "thin_prism"})
    s = wait_state(c, lambda s: s["solve"]["current"] and s["lens"]["solved_with"] == "thin_prism")
    rep = c.get(f"{API}/result").json()
    assert rep["camera"]["model"] == "rational_polynomial" and len(rep["camera"]["dist"]) == 12
    assert list(rep["std"])[-4:] == ["s1", "s2", "s3", "s4"]
    c.post(f"{API}/lens", json={"model": "fisheye"})
    wait_state(c, lambda s: s["solve"]["current"] and s["lens"]["solved_with"] == "fisheye")
    # the choice is kept with the session
    assert json.loads((session_dir(c) / "session.json").read_text())["lens_model"] == "fisheye"
    for bad in ({"model": "kannala"}, {"model": "auto", "x": 1}, {}):
        assert c.post(f"{API}/lens", json=bad).status_code == 422


def test_board_pdf_of_the_session_board(make_client):
    import pymupdf

    c = make_client(no_camera)
    for paper, size in (("A4", (297.0, 210.0)), ("A3", (420.0, 297.0)),
                        ("Letter", (279.4, 215.9))):
        r = c.get(f"{API}/board.pdf", params={"paper": paper})
        assert r.status_code == 200 and r.headers["content-type"] == "application/pdf"
        assert f"chessboard-9x6-{paper}.pdf" in r.headers["content-disposition"]
        page = pymupdf.open(stream=r.content, filetype="pdf")[0]
        assert (round(page.rect.width * 25.4 / 72, 1), round(page.rect.height * 25.4 / 72, 1)) \
            == size
    assert c.get(f"{API}/board.pdf", params={"paper": "A5"}).status_code == 422


def test_the_measured_square_size_scales_the_board_not_the_lens(make_client, wait_state):
    # a camera's session (not the sample): the page asks for the square size before solving
    c = make_client(no_camera, source="/dev/video-test")
    assert c.get(f"{API}/state").json()["session"]["square_measured"] is False
    upload(c, [(f"view_{i:02d}.jpg", _jpeg_bytes(i)) for i in range(10)])
    assert c.post(f"{API}/solve").status_code == 202
    wait_state(c, lambda s: s["solve"]["has_result"] and s["solve"]["current"])
    before = c.get(f"{API}/result").json()
    # the print came out at half the size: the views stay, the lens does not change, every
    # board is half as far
    r = c.post(f"{API}/square", json={"square_m": 0.0125})
    assert r.status_code == 200 and r.json() == {"square_mm": 12.5, "square_measured": True}
    s = wait_state(c, lambda s: s["solve"]["current"] and not s["solve"]["solving"])
    assert s["session"]["square_mm"] == 12.5 and s["session"]["square_measured"] is True
    assert len(s["views"]) == 10
    after = c.get(f"{API}/result").json()
    for k in ("fx", "fy", "cx", "cy"):
        assert abs(after["camera"][k] - before["camera"][k]) < 1e-3 * before["camera"][k], k
    for a, b in zip(after["per_view"], before["per_view"], strict=True):
        assert np.allclose(np.asarray(a["tvec"]), 0.5 * np.asarray(b["tvec"]), rtol=1e-3,
                           atol=1e-5)
    saved = json.loads((session_dir(c) / "session.json").read_text())
    assert saved["square_measured"] is True
    assert saved["session"]["board"]["square_m"] == 0.0125
    for bad in ({"square_m": 0}, {"square_m": 2}, {"square_m": "x"}, {}, {"square_m": 0.02,
                                                                         "x": 1}):
        assert c.post(f"{API}/square", json=bad).status_code == 422, bad
    assert c.post(f"{API}/square", content=b'{"square_m": NaN}',
                  headers={"content-type": "application/json"}).status_code == 422


def test_the_page_offers_every_lens_model_the_calibration_knows(make_client):
    import typing

    from drovisio.calibration.solve import MODEL_CHOICES
    from webtool.calibration.routes import LensBody

    assert typing.get_args(LensBody.model_fields["model"].annotation) == MODEL_CHOICES
    html = make_client(no_camera).get("/calibration").text
    lens = html.split('id="lens"')[1].split("</select>")[0]
    offered = re.findall(r'<option value="([a-z_]+)"', lens)
    assert sorted(offered) == sorted(MODEL_CHOICES)


def test_the_first_frame_is_waited_for_while_the_camera_starts():
    """A page's first request (no ``after``) waits for the camera's first picture instead of
    being told "Starting the camera…" at once."""
    from webtool.calibration.feed import CameraFeed

    go = threading.Event()

    class Slow(ScriptedSource):
        def open(self) -> None:
            go.wait(30)

    feed = CameraFeed(lambda: Slow(still([0]), hold=True),
                      on_frame=lambda f: feed.publish(f, b"\xff\xd8jpeg", lambda: None),
                      views=lambda: 0, on_read_error=lambda _m: None)

    async def main() -> tuple[bytes | None, int]:
        feed.touch()
        waiting = asyncio.create_task(feed.latest_frame(-1, wait=60))  # a bound, not a timing
        await asyncio.sleep(0.1)
        assert not waiting.done() and feed.status.state == "starting"
        go.set()
        return await asyncio.wait_for(waiting, 90)

    try:
        data, seq = asyncio.run(main())
    finally:
        feed.close()
    assert data == b"\xff\xd8jpeg" and seq >= 1
