"""Mount files and frame sources (files, folders, newest-frame policy)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio.mount import MountError, load_mount
from drovisio.sources import FrameSource, ImageFolderReader, SourceState, reader_for

APPROACH = Path(__file__).resolve().parents[2] / "sample_sessions" / "approach"


def test_sample_mount_and_gravity(tmp_path):
    m = load_mount(APPROACH / "mount.json")
    g0 = json.loads((APPROACH / "gravity.jsonl").read_text().splitlines()[0])["gravity"]
    assert np.allclose(m.gravity_in_camera(), g0, atol=1e-6)  # frame 0: level
    assert np.allclose(m.point_in_body([0, 0, 0]), [0.08, 0.0, 0.05])
    y = tmp_path / "mount.yaml"
    y.write_text("schema: drovisio/mount@1\nbody_frame: FRD\nbody_from_camera:\n"
                 "  - [0, -1, 0, 0]\n  - [1, 0, 0, 0]\n  - [0, 0, 1, 0]\n  - [0, 0, 0, 1]\n")
    assert np.allclose(load_mount(y).gravity_in_camera(), [0, 0, 1])


@pytest.mark.parametrize("text, words", [
    ('{"schema": "drovisio/mount@2", "body_from_camera": []}', ["schema"]),
    ('{"schema": "drovisio/mount@1", "body_from_camera": [[2,0,0,0],[0,1,0,0],[0,0,1,0],'
     '[0,0,0,1]]}', ["body_from_camera", "orthonormal"]),
    ('{"schema": "drovisio/mount@1", "body_frame": "NED", "body_from_camera": '
     '[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}', ["body_frame"]),
    ("[1, 2", ["invalid JSON"]),
])
def test_bad_mount_files_are_named(tmp_path, text, words):
    f = tmp_path / "m.json"
    f.write_text(text)
    with pytest.raises(MountError) as e:
        load_mount(f)
    assert str(f) in str(e.value) and all(w in str(e.value) for w in words)


def test_reader_kinds(tmp_path):
    assert type(reader_for("0")).__name__ == "CameraReader"
    assert type(reader_for("rtsp://10.0.0.2/stream")).__name__ == "StreamReader"
    assert type(reader_for(str(APPROACH / "approach.mp4"))).__name__ == "VideoFileReader"
    assert type(reader_for(str(tmp_path))).__name__ == "ImageFolderReader"


def test_a_number_is_a_camera_even_beside_a_folder_of_that_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert reader_for("3").label == "camera 3"
    (tmp_path / "3").mkdir()
    cam = reader_for("3")
    assert type(cam).__name__ == "CameraReader" and cam.index == 3
    assert cam.label == "camera 3 (not the file or folder 3 here: that is ./3)"
    assert type(reader_for("./3")).__name__ == "ImageFolderReader"


class _Lossless:
    """A reader whose frames are each handed over (the consumer's pace, none dropped)."""

    lossless = True

    def __init__(self, reader):
        self.reader, self.label, self.finite = reader, reader.label, reader.finite

    def open(self):
        self.reader.open()

    def read(self):
        return self.reader.read()

    def close(self):
        self.reader.close()


class _VirtualTime(FrameSource):
    """A source whose pacing waits move a virtual monotonic clock instead of taking time:
    when frames are due does not depend on how fast a loaded machine decodes them."""

    def __init__(self, reader, **kw):
        self.t = 1000.0
        super().__init__(reader, clock=(lambda: self.t, time.time), **kw)

    def _sleep(self, s: float) -> None:
        self.t += max(0.0, s)


def test_video_plays_at_its_frame_rate():
    before = time.time()
    src = _VirtualTime(_Lossless(reader_for(str(APPROACH / "approach.mp4"))),
                       pace="realtime")
    start = src.t
    src.start()
    frames = []
    try:
        while len(frames) < 8:
            f = src.get(60)
            assert f is not None
            frames.append(f)
    finally:
        src.stop()
    after = time.time()
    # each frame handed over when due at the video's 15 fps, the first at once
    assert [f.index for f in frames] == list(range(8))
    assert [f.t_mono - start for f in frames] == pytest.approx(
        [k / 15 for k in range(8)], abs=1e-3)
    assert before <= frames[0].t_wall <= after      # stamped with the wall clock


def test_image_folder_in_name_order_then_ends(tmp_path):
    for name in ["b.png", "a.png", "c.png"]:
        cv2.imwrite(str(tmp_path / name), np.full((8, 8, 3), ord(name[0]), np.uint8))
    (tmp_path / "notes.txt").write_text("not an image")
    src = FrameSource(ImageFolderReader(tmp_path, fps=100), pace="max").start()
    names = []
    while (f := src.get(60)) is not None:    # None: the folder ended
        names.append(f.name)
    assert names == ["a.png", "b.png", "c.png"] and src.state == SourceState.ENDED


def test_missing_camera_is_lost_and_retried_not_raised(until):
    src = FrameSource(reader_for("/dev/video97"), backoff=(0.02, 0.05)).start()
    try:
        until(lambda: src.status().state != "starting")
        st = src.status()
    finally:
        src.stop()
    assert st.state == "lost" and st.error and st.frames == 0


class _FakeV4L2:
    """A fake camera device: numbered frames at ~200 fps; ``unplugged`` makes reads fail and
    opening impossible; counts the open devices (a real one can be open once only)."""

    open_now = 0
    opened = 0
    unplugged = False

    def __init__(self, index, *args):
        self.ok = not _FakeV4L2.unplugged and _FakeV4L2.open_now == 0
        if self.ok:
            _FakeV4L2.open_now += 1
            _FakeV4L2.opened += 1
        self.n = 0

    def isOpened(self):  # noqa: N802 - cv2's name
        return self.ok

    def read(self):
        time.sleep(0.005)
        if _FakeV4L2.unplugged:
            return False, None
        self.n += 1
        return True, np.full((48, 64, 3), self.n % 256, np.uint8)

    def release(self):
        if self.ok:
            _FakeV4L2.open_now -= 1
            self.ok = False


def test_one_camera_shared_by_the_live_view_and_the_calibration_page(monkeypatch, until):
    """Two users of camera 0 in one process (the live pipeline's reader and the calibration
    page's source): the device is opened once, both get fresh frames, an unplug reaches both
    and they recover; the device closes when the last user goes."""
    from drovisio.sources import SharedCamera

    monkeypatch.setattr(SharedCamera, "opener", staticmethod(_FakeV4L2))
    monkeypatch.setattr(_FakeV4L2, "open_now", 0)
    monkeypatch.setattr(_FakeV4L2, "opened", 0)
    monkeypatch.setattr(_FakeV4L2, "unplugged", False)
    live = FrameSource(reader_for("/dev/video0"), backoff=(0.02, 0.05)).start()
    calib = reader_for("0")   # the calibration page pulls frames from the same reader kind
    calib.open()

    def pull():
        raw = calib.read()
        return None if raw is None else raw.image

    try:
        seen = [pull() for _ in range(5)]
        assert all(f is not None and f.shape == (48, 64, 3) for f in seen)
        assert len({int(f[0, 0, 0]) for f in seen}) == 5           # a new frame each read
        fr = live.get(timeout=60)
        assert fr is not None and live.status().state == "live"
        assert _FakeV4L2.open_now == 1 and _FakeV4L2.opened == 1    # one open device
        # unplugged: both see the loss, nothing raises; plugged back: both recover
        _FakeV4L2.unplugged = True
        until(lambda: live.status().state == "lost")
        assert pull() is None
        _FakeV4L2.unplugged = False
        until(lambda: live.status().state == "live")
        assert pull() is not None and _FakeV4L2.open_now == 1
    finally:
        live.stop()
        calib.close()
    until(lambda: _FakeV4L2.open_now == 0)
    assert not SharedCamera._registry
