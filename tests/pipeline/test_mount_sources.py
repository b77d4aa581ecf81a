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
    ("[1, 2", ["not valid JSON"]),
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


def test_video_plays_at_its_frame_rate():
    src = FrameSource(reader_for(str(APPROACH / "approach.mp4")), pace="realtime").start()
    frames = []
    t0 = time.monotonic()
    while len(frames) < 8:
        f = src.get(1.0)
        assert f is not None
        frames.append(f)
    src.stop()
    dt = np.diff([f.t_mono for f in frames])
    assert np.median(dt) == pytest.approx(1 / 15, abs=0.01)
    assert frames[0].t_wall == pytest.approx(time.time(), abs=2.0)
    assert time.monotonic() - t0 < 2.0


def test_image_folder_in_name_order_then_ends(tmp_path):
    for name in ["b.png", "a.png", "c.png"]:
        cv2.imwrite(str(tmp_path / name), np.full((8, 8, 3), ord(name[0]), np.uint8))
    (tmp_path / "notes.txt").write_text("not an image")
    src = FrameSource(ImageFolderReader(tmp_path, fps=100), pace="max").start()
    names = []
    while (f := src.get(1.0)) is not None:
        names.append(f.name)
    assert names == ["a.png", "b.png", "c.png"] and src.state == SourceState.ENDED


def test_missing_camera_is_lost_and_retried_not_raised():
    src = FrameSource(reader_for("/dev/video97"), backoff=(0.02, 0.05)).start()
    time.sleep(0.3)
    st = src.status()
    src.stop()
    assert st.state == "lost" and st.error and st.frames == 0
