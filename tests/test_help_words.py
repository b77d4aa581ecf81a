"""The help a newcomer reads: every command and sub-command listed, no raw markup, the same
file names as the README."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from drovisio import cli

README = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")


def _help(argv: list[str], capsys) -> str:
    try:
        rc = cli.main([*argv, "--help"])
    except SystemExit as e:
        rc = e.code
    assert rc in (0, None)
    return capsys.readouterr().out


def test_top_level_help_lists_every_command_and_sub_command(capsys):
    out = _help([], capsys)
    assert "SUPPRESS" not in out
    for cmd in cli.COMMANDS.values():
        assert re.search(rf"^\s+{re.escape(cmd.spelled or cmd.name)}\b", out, re.M), cmd.name
    for line in ("bench aruco|dots|lens|pipeline|real|renderer", "study run|example",
                 "mission check|simulate|landing|diagram", "autopilot check", "synth samples"):
        assert line in out, line


def test_bench_help_is_plain_text(capsys):
    for name in ("renderer", "lens"):
        out = subprocess.run([sys.executable, "-m", "drovisio", "bench", name, "--help"],
                             capture_output=True, text=True, timeout=120).stdout
        assert out.startswith("usage: drovisio bench " + name), out[:80]
        assert "``" not in out and "**" not in out and ":mod:" not in out, out


def test_plain_help_keeps_the_words():
    assert cli.plain_help("``drovisio x``: **edge** by :func:`~drovisio.mount.measure_mount`") \
        == "drovisio x: edge by measure_mount"


def test_run_help_and_readme_name_the_mount_file_alike(capsys):
    out = _help(["run"], capsys)
    assert "mount.yaml" not in out and "mount.json" in out
    assert "mount.yaml" not in README


def test_calibrate_mount_help_example_uses_shipped_pictures(capsys):
    out = _help(["calibrate", "mount"], capsys)
    assert "sample_sessions/pad" in out and "pad_pictures" not in out
