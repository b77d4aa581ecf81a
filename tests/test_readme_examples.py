"""Every `drovisio ...` example of the README works as printed, from a folder laid out like a
fresh clone (the shipped sample data and layouts where the examples name them).

The quick ones run to the end (their outputs are checked); those that run for minutes or
forever (serve, bench, the full study, regenerating the samples) are parsed by the real CLI
and the files they name must exist, so that a typo or a renamed option fails here."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from drovisio.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
# a shell line continued with a backslash is one example
README = re.sub(r"\\\n\s*", " ", (ROOT / "README.md").read_text(encoding="utf-8"))
#: (command words) whose examples run to the end here (each well under a minute)
RUN = {("detect",), ("calibrate",), ("calibrate", "board"), ("calibrate", "mount"), ("run",),
       ("mission", "check"), ("mission", "diagram"), ("study", "example")}


def _examples() -> list[str]:
    found = re.findall(r"`(drovisio [^`]+)`", README)
    found += re.findall(r"^(drovisio [^\n#]+?)\s*(?:#.*)?$", README, re.M)
    out = []
    for cmd in found:
        if "[" in cmd or re.search(r"\b[A-Z]{3,}\b", cmd) or "..." in cmd or cmd.strip() in (
                "drovisio serve", "drovisio detect", "drovisio calibrate", "drovisio run",
                "drovisio mission"):
            continue            # a name in a sentence or a synopsis (PLACEHOLDERS), not an example
        if tuple(cmd.split()[1:]) in RUN:
            continue            # a command named in a sentence: every one of them takes arguments
        out.append(" ".join(cmd.split()))
    return list(dict.fromkeys(out))


EXAMPLES = _examples()


def _on_hardware(argv: list[str]) -> bool:
    """An example for the drone itself (a camera index, a serial link): parsed, not run."""
    return any(a.isdigit() and p == "--source" for p, a in zip(argv, argv[1:])) or any(
        "/dev/" in a for a in argv)


def _words(cmd: str) -> tuple[str, ...]:
    argv = shlex.split(cmd)[1:]
    if _on_hardware(argv):
        return ("(on the drone)",)
    head = tuple(a for a in argv[:2] if not a.startswith("-"))
    for n in (2, 1):
        if head[:n] in RUN:
            return head[:n]
    return head[:1]


def test_the_readme_has_the_examples_we_expect():
    names = {_words(c) for c in EXAMPLES}
    assert names >= RUN | {("serve",), ("bench",), ("study",), ("synth",)}, names


@pytest.fixture(scope="module")
def clone(tmp_path_factory) -> Path:
    """A folder like a fresh clone's root: the shipped data the examples name."""
    d = tmp_path_factory.mktemp("clone")
    for name in ("sample_sessions", "marker_layouts"):
        (d / name).symlink_to(ROOT / name, target_is_directory=True)
    return d


@pytest.mark.parametrize("cmd", [c for c in EXAMPLES if _words(c) not in RUN])
def test_long_examples_parse_and_name_existing_files(cmd):
    argv = shlex.split(cmd)[1:]
    build_parser().parse_args(argv)      # exits (fails the test) on any unknown option
    for a in argv:
        if a.startswith(("sample_sessions/", "marker_layouts/")) and a.endswith(
                (".json", ".yaml", ".mp4", ".jsonl")):
            assert (ROOT / a).is_file(), a


@pytest.mark.parametrize("cmd", [c for c in EXAMPLES if _words(c) in RUN])
def test_quick_examples_run_as_printed(cmd, clone, tmp_path):
    # each example in its own copy of the clone's root (the outputs land there)
    work = tmp_path / "work"
    work.mkdir()
    for name in ("sample_sessions", "marker_layouts"):
        (work / name).symlink_to(clone / name, target_is_directory=True)
    if "my_study/protocol.yaml" in cmd:
        pytest.skip("needs `drovisio study example` first: run by its own example")
    r = subprocess.run([sys.executable, "-m", "drovisio", *shlex.split(cmd)[1:]], cwd=work,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, (cmd, r.stderr[-2000:])
    assert "Traceback" not in r.stderr
    words = _words(cmd)
    if words == ("detect",):
        lines = [json.loads(x) for x in r.stdout.splitlines()]
        assert len(lines) == 150 and sum(len(x["bricks"]) for x in lines) > 150
    elif words == ("calibrate",):
        rep = json.loads((work / "report.json").read_text())
        assert (work / "camera.yaml").is_file() and rep["rms_px"] < 0.5
    elif words == ("calibrate", "board"):
        assert (work / "board.pdf").read_bytes()[:5] == b"%PDF-"
    elif words == ("calibrate", "mount"):
        from drovisio.mount import load_mount

        a = load_mount(work / "mount.json").angles()
        assert abs(a["tilt_deg"] - 20.0) < 0.3 and abs(a["pan_deg"]) < 0.3
    elif words == ("run",):
        out = [json.loads(x) for x in r.stdout.splitlines() if x.startswith("{")]
        # played like a camera (realtime pace): how many frames a machine measures is its
        # speed (a loaded one takes the newest frame and skips the rest); none is repeated or
        # out of order, and the video plays to its last frame
        frames = [d["frame"] for d in out]
        assert frames and frames == sorted(set(frames)) and frames[-1] == 149, frames
    elif words == ("study", "example"):
        proto = work / "my_study" / "protocol.yaml"
        assert proto.is_file()
        # the README's next step on it, as printed but bounded (its frame-rate and memory
        # runs take minutes): --quick and a one-second memory run
        follow = "drovisio study run --protocol my_study/protocol.yaml --out my_study/report"
        assert follow in EXAMPLES
        r = subprocess.run([sys.executable, "-m", "drovisio", *shlex.split(follow)[1:],
                            "--quick", "--memory-seconds", "1"],
                           cwd=work, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr[-2000:]
        assert (work / "my_study" / "report" / "report.html").is_file()
