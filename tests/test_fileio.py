"""drovisio.fileio: the one atomic-write mechanism (temporary file, then rename)."""

from __future__ import annotations

import os
import stat

import pytest

from drovisio.fileio import atomic_write, atomic_write_bytes


def test_writes_replaces_and_leaves_no_temporary_file(tmp_path):
    p = tmp_path / "a.json"
    atomic_write_bytes(p, b"one")
    atomic_write_bytes(p, b"two", mode=0o644)
    assert p.read_bytes() == b"two" and stat.S_IMODE(p.stat().st_mode) == 0o644
    assert os.listdir(tmp_path) == ["a.json"]


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


def test_missing_folder(tmp_path):
    with pytest.raises(FileNotFoundError):
        atomic_write_bytes(tmp_path / "no" / "a.bin", b"x")
    atomic_write_bytes(tmp_path / "no" / "a.bin", b"x", make_parents=True)
    assert (tmp_path / "no" / "a.bin").read_bytes() == b"x"
