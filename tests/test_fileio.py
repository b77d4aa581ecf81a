"""drovisio.fileio: the one writer (temporary file, check, rename) that loses nothing."""

from __future__ import annotations

import errno
import os
import stat
import subprocess
from pathlib import Path

import pytest

from drovisio.errors import WriteError
from drovisio.fileio import (
    APPENDED,
    FILE,
    FOLDER,
    atomic_write,
    atomic_write_bytes,
    check_output_path,
    check_outputs,
)


def test_writes_replaces_and_leaves_no_temporary_file(tmp_path):
    p = tmp_path / "a.json"
    atomic_write_bytes(p, b"one")
    atomic_write_bytes(p, b"two", mode=0o644)
    assert p.read_bytes() == b"two" and stat.S_IMODE(p.stat().st_mode) == 0o644
    assert os.listdir(tmp_path) == ["a.json"]


def test_permissions_follow_the_umask_and_the_replaced_file(tmp_path):
    old = os.umask(0o022)
    try:
        new = atomic_write_bytes(tmp_path / "new.yaml", b"x")
        assert stat.S_IMODE(new.stat().st_mode) == 0o644   # not mkstemp's 0600
        kept = tmp_path / "kept.yaml"
        kept.write_bytes(b"old")
        kept.chmod(0o640)
        atomic_write_bytes(kept, b"new")
        assert stat.S_IMODE(kept.stat().st_mode) == 0o640
    finally:
        os.umask(old)


def test_no_overwrite_keeps_the_file_already_saved(tmp_path):
    p = tmp_path / "a.json"
    p.write_bytes(b"saved")
    with pytest.raises(FileExistsError):
        atomic_write_bytes(p, b"new", overwrite=False)
    assert p.read_bytes() == b"saved" and os.listdir(tmp_path) == ["a.json"]


def test_a_failing_writer_loses_nothing(tmp_path):
    p = tmp_path / "cam.yaml"
    p.write_text("old")

    def broken(tmp):
        tmp.write_text("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic_write(p, broken, suffix=".yaml")
    assert p.read_text() == "old" and os.listdir(tmp_path) == ["cam.yaml"]


def test_a_writer_that_silently_writes_nothing_replaces_nothing(tmp_path):
    """OpenCV's FileStorage on a full disk: no exception, an empty file."""
    p = tmp_path / "cam.yaml"
    p.write_text("old camera")
    with pytest.raises(WriteError, match="cam.yaml: not written: the result was empty"):
        atomic_write(p, lambda tmp: None, suffix=".yaml")
    assert p.read_text() == "old camera" and os.listdir(tmp_path) == ["cam.yaml"]


def test_verify_failure_replaces_nothing(tmp_path):
    p = tmp_path / "cam.yaml"
    p.write_text("old camera")

    def verify(tmp):
        raise ValueError("parsed back to something else")

    with pytest.raises(WriteError, match="reading it back failed .parsed back"):
        atomic_write(p, lambda tmp: tmp.write_text("new"), verify=verify)
    assert p.read_text() == "old camera" and os.listdir(tmp_path) == ["cam.yaml"]


def test_enospc_is_one_line_and_replaces_nothing(tmp_path):
    p = tmp_path / "cam.yaml"
    p.write_text("old camera")

    def full(tmp):
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(WriteError) as e:
        atomic_write(p, full)
    assert str(e.value) == (f"{p}: not written: the disk is full; free some space and try "
                            "again (any previous file is kept)")
    assert p.read_text() == "old camera" and os.listdir(tmp_path) == ["cam.yaml"]


def test_missing_folder(tmp_path):
    with pytest.raises(WriteError, match="the folder does not exist"):
        atomic_write_bytes(tmp_path / "no" / "a.bin", b"x")
    atomic_write_bytes(tmp_path / "no" / "a.bin", b"x", make_parents=True)
    assert (tmp_path / "no" / "a.bin").read_bytes() == b"x"


def test_output_path_checks(tmp_path):
    cam = tmp_path / "cam.yaml"
    cam.write_text("x")
    with pytest.raises(WriteError, match="same file as the camera file"):
        check_output_path(cam, "--out", {"the camera file": cam})
    with pytest.raises(WriteError, match="is a folder"):
        check_output_path(tmp_path, "--out")
    assert check_output_path(tmp_path / "o.jsonl", "--out", {"input": cam}) == \
        tmp_path / "o.jsonl"


def _tmpfs(path: Path, size: str) -> bool:
    path.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                       capture_output=True)
    return r.returncode == 0


@pytest.fixture
def small_disk(tmp_path):
    """A 64 KiB tmpfs (needs root, as in CI); else the test runs on a simulated full disk."""
    d = tmp_path / "disk"
    if not _tmpfs(d, "64k"):
        yield None
        return
    try:
        yield d
    finally:
        subprocess.run(["umount", str(d)], capture_output=True)


def test_full_disk_keeps_the_previous_camera_file_byte_identical(small_disk, tmp_path,
                                                                  monkeypatch):
    from drovisio.camera import Camera
    from drovisio.camera_file import load_camera, save_camera

    folder = small_disk or tmp_path
    cam_path = folder / "camera.yaml"
    save_camera(Camera.drone_webcam(), cam_path)
    before = cam_path.read_bytes()
    if small_disk is not None:
        fd = os.open(folder / "filler.bin", os.O_WRONLY | os.O_CREAT)
        try:                                           # fill the disk to the last byte
            for chunk in (4096, 512, 1):
                try:
                    while True:
                        os.write(fd, b"\0" * chunk)
                except OSError:
                    pass
        finally:
            os.close(fd)
    else:   # simulate: every write the camera writer makes fails as a full disk does
        import drovisio.fileio as fileio

        real = fileio.atomic_write

        def full(path, write_to_tmp, **kw):
            def fails(tmp):
                write_to_tmp(tmp)
                tmp.write_bytes(b"")
            return real(path, fails, **kw)

        monkeypatch.setattr("drovisio.camera_file.atomic_write", full)
    other = Camera.from_fov(640, 480, 75.0, name="other")
    with pytest.raises(WriteError) as e:
        save_camera(other, cam_path)
    assert "\n" not in str(e.value) and str(cam_path) in str(e.value)
    assert cam_path.read_bytes() == before
    assert load_camera(cam_path).almost_equal(Camera.drone_webcam())
    assert sorted(p.name for p in folder.iterdir() if p.name.startswith(".")) == []


def _folder_of_images(d: Path) -> Path:
    d.mkdir()
    (d / "a.jpg").write_bytes(b"an input image")
    return d


def test_an_output_among_what_an_input_folder_reads_is_refused(tmp_path):
    images = _folder_of_images(tmp_path / "images")
    (tmp_path / "link").symlink_to(images)
    inputs = {"input images": images}
    for out, kind in ((images / "a.jpg", FILE), (images / "new.png", APPENDED),
                      (tmp_path / "link" / "b.mp4", FILE), (images, FOLDER)):
        with pytest.raises(WriteError) as e:
            check_outputs([("--out", out, kind)], inputs)
        assert str(e.value) == (f"{out}: --out would land among what the command reads "
                                "from input images; choose another folder")
    assert (images / "a.jpg").read_bytes() == b"an input image"
    # what a folder of images does not read: its other files, its subfolders
    check_outputs([("--out", images / "poses.jsonl", FILE), ("--record", images / "rec", FOLDER)],
                  inputs)


def test_anything_inside_a_recording_read_as_input_is_refused(tmp_path):
    rec = tmp_path / "rec"
    (rec / "frames").mkdir(parents=True)
    (rec / "recording.json").write_text("{}")
    for out in (rec / "frames.jsonl", rec / "frames" / "x.txt"):
        with pytest.raises(WriteError, match="would land among what the command reads from "
                                             "--source"):
            check_outputs([("--sink jsonl:PATH", out, APPENDED)], {"--source rec": rec})


def test_outputs_must_be_distinct(tmp_path):
    rec = tmp_path / "r.mcap"
    with pytest.raises(WriteError) as e:
        check_outputs([("--record", rec, FILE), ("--sink jsonl:PATH", rec, APPENDED)], {})
    assert str(e.value) == (f"{rec}: --sink jsonl:PATH is the same file as --record; give "
                            "each output its own name")
    x = tmp_path / "x.jsonl"
    with pytest.raises(WriteError, match="is given twice; give each output its own name"):
        check_outputs([("--sink jsonl:PATH", x, APPENDED),
                       ("--sink jsonl:PATH", tmp_path / "." / "x.jsonl", APPENDED)], {})
    folder = tmp_path / "dir"
    for first, second in (((("--record", folder, FOLDER)),
                           ("--sink jsonl:PATH", folder / "frames.jsonl", APPENDED)),
                          (("--sink jsonl:PATH", folder / "frames.jsonl", APPENDED),
                           ("--record", folder, FOLDER))):
        with pytest.raises(WriteError) as e:
            check_outputs([first, second], {})
        assert str(e.value) == (f"{folder / 'frames.jsonl'}: --sink jsonl:PATH lies inside "
                                f"--record's folder {folder}; give it a place outside")
    check_outputs([("--record", folder, FOLDER), ("--sink jsonl:PATH", x, APPENDED)], {})
