"""Class: whole argument vectors over a broad alphabet, for every command.

Hypothesis builds command lines from each command's own options (read from its parser), in
any order and number, with values drawn from a broad alphabet: any printable or control
character, the surrogate escapes Python gives to bytes a file name cannot decode, option
look-alikes (``-``, ``--``, ``--x=``), paths that are not files (``/dev/stdin``, a FIFO,
``/proc/self/mem``), names of 300 bytes, numbers of 5,000 digits. Each line runs in full
(through ``main``, a deadline on each) from a scratch folder; the commands that would run
for minutes when given a valid line (benches, study, synthetic samples, simulations) are
parsed and guarded only, with their work stubbed. Whatever the line: exit 0, 1 or 2, never
a traceback or an internal error, no hang, and nothing written outside the scratch folder.
"""

from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

#: bounded, derandomized, no wall-clock deadline (as the suite's other hypothesis tests)
HOSTILE = settings(max_examples=100, deadline=None, derandomize=True, database=None,
                   suppress_health_check=[HealthCheck.too_slow,
                                          HealthCheck.function_scoped_fixture,
                                          HealthCheck.data_too_large])

REPO = Path(__file__).resolve().parents[2]


def _leaves() -> dict[str, argparse.ArgumentParser]:
    from drovisio.cli import build_parser

    out: dict[str, argparse.ArgumentParser] = {}

    def walk(p: argparse.ArgumentParser, words: list[str]) -> None:
        subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            out[" ".join(words)] = p
        for s in subs:
            for name, sp in s.choices.items():
                walk(sp, [*words, name])

    walk(build_parser(), [])
    return out


LEAVES = _leaves()
#: commands whose valid lines run for minutes, or open what a line names as a device: parsed
#: and guarded (``main`` up to the command's entry), their work stubbed
STUBBED = {"bench", "study run", "study example", "synth samples", "mission simulate",
           "autopilot check", "calibrate"}
OPTIONS = {w: sorted({s for a in p._actions if a.option_strings and a.dest != "help"
                      for s in a.option_strings if s.startswith("--")})
           for w, p in LEAVES.items()}

_chars = st.characters(blacklist_categories=("Cs",)) | st.sampled_from(
    [chr(c) for c in range(0xDC80, 0xDD00, 7)])   # surrogate escapes of undecodable bytes


def _relative(s: str) -> str:
    # an absolute name made up at random could land anywhere on this machine
    return "x" + s if s.startswith(("/", "\\")) else s


hostile_value = (
    st.text(_chars, max_size=24).map(_relative)
    | st.sampled_from(["-", "--", "--x=", "=", "-1", "0", "1e400", "nan", "9" * 5000,
                       "n" * 300, "a\nb", "\t", "../" * 30 + "etc/passwd", "/dev/stdin",
                       "/dev/zero", "/proc/self/mem", "FIFO", "jsonl:FIFO", "mavlink:",
                       "udp:", "udp:256.1.1.1:99999", "ws://[::1", "jsonl:", "%s%n", "{}",
                       "charuco:9x6:DICT_APRILTAG_16h5", "chessboard:0x0", "aruco:1x1"])
)


def _base(words: str, f: dict) -> list[str]:
    """A line of ``words`` that would run (the hostile part goes after it: argparse keeps the
    last value of an option, so the line reaches the command's own checks)."""
    cam, lay, images = str(f["camera"]), str(f["layout"]), str(f["images"])
    return {
        "detect": ["--camera", cam, "--layout", lay, str(f["video"])],
        "calibrate-mount": ["--camera", cam, "--layout", str(f["pad"]), "--out", "m.json",
                            images],
        "calibrate-board": ["--pdf", "b.pdf"],
        "run": ["--camera", cam, "--layout", lay, "--sink", "jsonl:out.jsonl"],
        "serve": ["--camera", cam, "--layout", lay],
        "mission check": ["wall-2-courses"],
        "mission landing": ["--camera", cam, "--mount", str(f["mount"])],
        "mission diagram": ["--out", "d.svg"],
        "study run": ["--out", "study", "--quick"],
        "study example": ["--out", "ex"],
        "calibrate": ["--board", "chessboard:9x6", "--square", "0.025", "--out", "c.yaml",
                      images],
    }.get(words, [])


@st.composite
def command_lines(draw, words_from: list[str], f: dict | None = None):
    words = draw(st.sampled_from(words_from))
    opts = OPTIONS[words]
    argv: list[str] = words.split()
    if f is not None and draw(st.booleans()):
        argv += _base(words, f)
    for _ in range(draw(st.integers(0, 4))):
        if opts and draw(st.booleans()):
            argv.append(draw(st.sampled_from(opts)))
        argv.append(draw(hostile_value))
    return words, argv


@pytest.fixture
def scratch(tmp_path, monkeypatch, hostile_files):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "FIFO").symlink_to(hostile_files["fifo"])
    return tmp_path


def _repo_state() -> str:
    return subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"],
                          cwd=REPO, capture_output=True, text=True).stdout


def _stoppers(words: str, f: dict) -> list[str]:
    """Options put last (the last one wins) so that a valid line ends quickly."""
    return {
        "run": ["--source", str(f["video"]), "--frames", "1", "--pace", "max", "--quiet"],
        "serve": ["--port", str(f["busy_port"])],
        "station": ["--port", str(f["busy_port"])],
        "mission landing": ["--runs", "1"],
    }.get(words, [])


FULL = sorted(w for w in LEAVES if w not in STUBBED)


@HOSTILE
@given(data=st.data())
def test_any_command_line_ends_in_one_line(cli, hostile_files, scratch, data):
    words, argv = data.draw(command_lines(FULL, hostile_files))
    rc, out, err = cli(*argv, *_stoppers(words, hostile_files), cls="cli argv: alphabet",
                       seconds=180)
    assert rc in (0, 1, 2), (argv, rc, err[-400:])
    assert "Traceback" not in err and "internal error" not in err, (argv, err[-400:])
    if rc == 2:
        last = err.strip().splitlines()[-1] if err.strip() else ""
        assert last and len(last) < 1000, (argv, err[-400:])


@HOSTILE
@given(data=st.data())
def test_long_commands_refuse_or_reach_their_work(cli, hostile_files, scratch, monkeypatch,
                                                  data):
    import drovisio.cli as cli_mod

    reached: list[str] = []

    def stub(args):
        reached.append(args.command)
        return 0

    monkeypatch.setattr(cli_mod, "resolve", lambda _entry: stub)
    words, argv = data.draw(command_lines(sorted(STUBBED), hostile_files))
    rc, out, err = cli(*argv, cls="cli argv: alphabet (parsed and guarded)", seconds=180)
    assert "Traceback" not in err and "internal error" not in err, (argv, err[-400:])
    assert rc in (0, 2), (argv, rc, err[-400:])
    assert (rc == 0) == bool(reached), (argv, err[-300:])


def test_nothing_was_written_outside_the_scratch_folders():
    # runs last in this file (pytest keeps the order): the fuzzed lines ran from scratch
    # folders; the repository holds what it held before (the suite's own edits aside)
    state = _repo_state()
    assert "sample_sessions/" not in state and "marker_layouts/" not in state, state
