"""The `drovisio` command line: commands, help, lazy dispatch, one handler for every error."""

from __future__ import annotations

import argparse
import subprocess
import sys
import types
from pathlib import Path

import pytest

from drovisio import cli

ALL_COMMANDS = ["detect", "calibrate", "run", "serve", "bench", "station", "study", "mission",
                "autopilot", "synth"]

# Minimal valid arguments per command (what DESIGN.md requires), for dispatch tests.
MINIMAL_ARGS = {
    "detect": ["--camera", "cam.yaml", "--layout", "l.json", "img.png"],
    "calibrate": ["--board", "chessboard:9x6", "--square", "0.025", "--out", "cam.yaml", "imgs/"],
    "run": ["--source", "0", "--camera", "cam.yaml", "--layout", "l.json"],
    "mission": [],
}


def test_table_lists_exactly_the_design_commands():
    assert [n for n, c in cli.COMMANDS.items() if not c.spelled] == ALL_COMMANDS
    # besides them, actions of calibrate spelled as two words: the board to print, the mount
    # (listed too, as people type them)
    assert [c.spelled for c in cli.COMMANDS.values() if c.spelled] == [
        "calibrate board", "calibrate mount"]
    assert all(c.summary for c in cli.COMMANDS.values())


def test_calibrate_board_is_an_action_of_calibrate(capsys):
    assert cli.main(["calibrate", "board", "--help"]) == 0
    assert capsys.readouterr().out.startswith("usage: drovisio calibrate board")
    # without --pdf, "board" is an image folder like any other
    a = cli.build_parser().parse_args(["calibrate", "board", "--board", "chessboard:9x6",
                                       "--square", "0.025", "--out", "c.yaml"])
    assert a.command == "calibrate" and a.images == ["board"]


def test_top_level_help_lists_all_commands(capsys):
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    for name in ALL_COMMANDS:
        assert f"\n    {name}" in out, name
    assert "Example" in out


@pytest.mark.parametrize("name", ALL_COMMANDS)
def test_each_command_help_has_description_and_example(name, capsys):
    assert cli.main([name, "--help"]) == 0
    out = capsys.readouterr().out
    assert f"usage: drovisio {name}" in out
    assert "Example:" in out
    assert f"drovisio {name}" in out.split("Example:")[1]
    assert cli.COMMANDS[name].description.split()[0] in out


def test_synth_samples_help_has_example(capsys):
    assert cli.main(["synth", "samples", "--help"]) == 0
    out = capsys.readouterr().out
    assert "--out" in out and "Example:" in out


def test_arguments_follow_design():
    parser = cli.build_parser()
    a = parser.parse_args(["detect", "--camera", "c.yaml", "--layout", "a.json", "--layout",
                           "b.json", "--method", "dots", "--gravity-file", "g.jsonl",
                           "--out", "o.jsonl", "x.png", "frames/"])
    assert a.layout == ["a.json", "b.json"] and a.method == "dots"
    assert a.gravity_file == "g.jsonl" and a.out == "o.jsonl" and a.inputs == ["x.png", "frames/"]
    a = parser.parse_args(["calibrate", "--board", "chessboard:9x6", "--square", "0.025",
                           "--report", "r.json", "--out", "cam.yaml", "imgs/"])
    assert a.square == 0.025 and a.report == "r.json" and a.images == ["imgs/"]
    # every lens model the calibration knows, and only those
    from drovisio.calibration.solve import MODEL_CHOICES

    model = next(x for x in parser._subparsers._group_actions[0].choices["calibrate"]._actions
                 if x.dest == "model")
    assert tuple(model.choices) == MODEL_CHOICES
    a = parser.parse_args(["run", "--source", "0", "--camera", "c.yaml", "--layout", "a.json",
                           "--mount", "m.yaml", "--sink", "jsonl:-", "--sink",
                           "udp://127.0.0.1:9000", "--record", "rec/"])
    assert a.sink == ["jsonl:-", "udp://127.0.0.1:9000"] and a.mount == "m.yaml"
    a = parser.parse_args(["serve"])
    assert (a.host, a.port, a.source, a.camera) == ("127.0.0.1", 8080, None, None)
    a = parser.parse_args(["synth", "samples", "--out", "somewhere"])
    assert a.out == Path("somewhere")


def test_usage_errors_exit_2(capsys):
    assert cli.main(["detect"]) == 2  # missing --camera, --layout, INPUT
    assert cli.main(["detect", "--camera", "c", "--layout", "l", "--method", "sift", "x"]) == 2
    assert cli.main([]) == 2
    assert cli.main(["no-such-command"]) == 2


@pytest.mark.parametrize("argv,line", [
    (["detect"], "drovisio detect: the following arguments are required: --camera, --layout, "
                 "INPUT (see drovisio detect --help)"),
    (["detect", "--camera", "c", "--layout", "l", "--method", "sift", "x"],
     "drovisio detect: argument --method: invalid choice: 'sift' (choose from 'auto', 'aruco', "
     "'dots') (see drovisio detect --help)"),
    (["calibrate", "mount", "--camera", "c"], "drovisio calibrate mount: the following "
     "arguments are required: --out, IMAGE_OR_FOLDER (see drovisio calibrate mount --help)"),
    (["study", "run"], "drovisio study run: the following arguments are required: --out "
                       "(see drovisio study run --help)"),
    (["bench", "real"], "drovisio bench real: the following arguments are required: DIR "
                        "(see drovisio bench real --help)"),
])
def test_a_usage_error_is_one_line_pointing_to_the_help(argv, line, capsys):
    assert cli.main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and err == line + "\n"     # no usage block: the help has it


COMMAND_LIST = ("the commands are detect, calibrate, run, serve, bench, station, study, "
                "mission, autopilot, synth (see drovisio --help)")


@pytest.mark.parametrize("word,hint", [
    ("calibrat", "did you mean 'calibrate'? "),
    ("calibrate-bord", "did you mean 'calibrate board'? "),
    ("mision", "did you mean 'mission'? "),
    ("foo", ""),
])
def test_an_unknown_command_lists_only_the_commands_users_type(word, hint, capsys):
    assert cli.main([word]) == 2
    out, err = capsys.readouterr()
    # the internal names of "calibrate board" and "calibrate mount" are never offered
    assert out == "" and err == f"drovisio: unknown command '{word}'; {hint}{COMMAND_LIST}\n"


def test_the_internal_names_still_run(capsys):
    # tests and scripts may type them; only the listing hides them
    assert cli.main(["calibrate-board", "--help"]) == 0
    assert capsys.readouterr().out.startswith("usage: drovisio calibrate board")
    assert cli.main(["calibrate-mount", "--help"]) == 0
    assert capsys.readouterr().out.startswith("usage: drovisio calibrate mount")
    # an action's parser keeps argparse's own list of its actions
    assert cli.main(["mission", "chek"]) == 2
    assert "invalid choice: 'chek' (choose from 'check', " in capsys.readouterr().err


def test_help_still_shows_the_usage_block(capsys):
    assert cli.main(["detect", "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: drovisio detect [-h] --camera CAMERA_FILE --layout "
                          "LAYOUT.json\n")
    assert "options:" in out and "Example:" in out


def test_bench_dispatches_by_name(monkeypatch, capsys):
    assert cli.main(["bench", "nonsense"]) == 2
    assert "unknown benchmark 'nonsense'" in capsys.readouterr().err
    seen = []
    module = types.ModuleType("drovisio.bench.fake")
    module.main = lambda argv: seen.append(argv) or 0
    monkeypatch.setitem(sys.modules, "drovisio.bench.fake", module)
    from drovisio.commands import bench

    monkeypatch.setitem(bench.BENCHMARKS, "fake", "a fake benchmark")
    assert cli.main(["bench", "fake", "--frames", "3"]) == 0
    assert seen == [["--frames", "3"]]


def test_new_implementation_is_picked_up_automatically(monkeypatch):
    """Adding drovisio/commands/detect.py with run(args) -> int is all it takes."""
    seen: list[argparse.Namespace] = []
    module = types.ModuleType("drovisio.commands.detect")
    module.run = lambda args: seen.append(args) or 0
    monkeypatch.setitem(sys.modules, "drovisio.commands.detect", module)
    assert cli.COMMANDS["detect"].entry_point == "drovisio.commands.detect:run"
    assert cli.main(["detect", *MINIMAL_ARGS["detect"]]) == 0
    assert seen and seen[0].camera == "cam.yaml" and seen[0].inputs == ["img.png"]


def _fake_command(monkeypatch, body):
    module = types.ModuleType("drovisio.commands.detect")
    module.run = body
    monkeypatch.setitem(sys.modules, "drovisio.commands.detect", module)


def test_bad_input_is_one_line_naming_the_file_and_exit_2(monkeypatch, capsys):
    from drovisio.errors import InputError

    def body(args):
        raise InputError("cam.yaml: image_width: 'abc' is not a whole number of pixels")

    _fake_command(monkeypatch, body)
    assert cli.main(["detect", *MINIMAL_ARGS["detect"]]) == 2
    err = capsys.readouterr().err
    assert err == ("drovisio detect: cam.yaml: image_width: 'abc' is not a whole number of "
                   "pixels\n")


def test_unexpected_error_is_one_line_with_the_traceback_in_a_file(monkeypatch, capsys):
    def body(args):
        return {}["boom"]

    _fake_command(monkeypatch, body)
    assert cli.main(["detect", *MINIMAL_ARGS["detect"]]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("drovisio detect: internal error: KeyError: 'boom'")
    path = err.split("full traceback in ")[1].split(";")[0]
    text = Path(path).read_text()
    assert "Traceback" in text and "KeyError" in text
    Path(path).unlink()
    with pytest.raises(KeyError):  # --debug lets it through, traceback and all
        cli.main(["--debug", "detect", *MINIMAL_ARGS["detect"]])


def test_broken_pipe_ends_quietly(monkeypatch, capsys):
    def body(args):
        raise BrokenPipeError

    _fake_command(monkeypatch, body)
    assert cli.main(["detect", *MINIMAL_ARGS["detect"]]) == cli.EXIT_BROKEN_PIPE
    assert capsys.readouterr().err == ""


def test_help_text_names_no_internal_tracking():
    """Nothing users read mentions issue numbers or unfinished work."""
    import re

    parser = cli.build_parser()
    texts = [parser.format_help()]
    for name in ALL_COMMANDS:
        texts.append(parser._subparsers._group_actions[0].choices[name].format_help())
    for t in texts:
        assert not re.search(r"issue #?\d|not (implemented|available) yet", t), t


def test_synth_samples_dispatches_to_synth_samples_main(monkeypatch, tmp_path):
    calls = []
    module = types.ModuleType("drovisio.synth_samples")
    module.main = lambda out_dir: calls.append(out_dir)
    monkeypatch.setitem(sys.modules, "drovisio.synth_samples", module)
    assert cli.main(["synth", "samples", "--out", str(tmp_path)]) == 0
    assert calls == [tmp_path]
    assert cli.main(["synth", "samples"]) == 0
    assert calls[1] is None  # synth_samples.main writes the shipped sample_sessions/


def test_help_does_not_import_heavy_modules():
    code = ("import sys; from drovisio.cli import main; main(['--help']); "
            "heavy = [m for m in ('cv2', 'fastapi', 'uvicorn', 'webtool', 'viser') if m in sys.modules]; "
            "print(heavy); sys.exit(1 if heavy else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr


def test_console_script_runs():
    exe = Path(sys.executable).with_name("drovisio")
    if not exe.exists():
        pytest.skip(f"{exe} not installed (run `make test`, which installs the package)")
    r = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60,
                       stdin=subprocess.DEVNULL)
    assert r.returncode == 0, r.stderr
    for name in ALL_COMMANDS:
        assert name in r.stdout
