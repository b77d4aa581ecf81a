"""Class: numeric arguments and files named on the command line, for every command.

Every numeric option of every command (benches included) given numbers no command can use
(huge, of thousands of digits, not finite, not numbers at all) and every file option given
things that are not files of that kind (a FIFO, a 10 GB sparse file, a folder, /dev/zero, a
name of 300 bytes, a NUL byte, ``../`` far up): exit 2 and one line that names the option,
before any work — never a traceback, an internal error or a hang (each call has a deadline).
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st


def _settings():
    from hypothesis import HealthCheck, settings

    return settings(max_examples=120, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


#: (command words, the option, how to build the rest of the command line around it)
NUMERIC = [
    ("calibrate", "--square"), ("calibrate board", "--square"), ("calibrate mount", "--offset"),
    ("run", "--max-age"), ("run", "--frames"), ("serve", "--port"), ("serve", "--max-age"),
    ("mission check", "--seed"), ("mission simulate", "--seed"),
    ("mission simulate", "--bricks"), ("mission simulate", "--ss"),
    ("mission simulate", "--render-rate"), ("mission simulate", "--heading-bias"),
    ("study run", "--frames"), ("study run", "--memory-seconds"), ("study example", "--frames"),
    ("bench aruco", "--frames"), ("bench aruco", "--empty"), ("bench aruco", "--seed"),
    ("bench aruco", "--threads"), ("bench aruco", "--repeat"), ("bench aruco", "--ss"),
    ("bench dots", "--frames"), ("bench dots", "--seed"), ("bench dots", "--threads"),
    ("bench dots", "--memory-frames"), ("bench lens", "--views"), ("bench lens", "--scenes"),
    ("bench lens", "--ss"), ("bench pipeline", "--fps"), ("bench pipeline", "--seconds"),
    ("bench pipeline", "--minutes"),
]


def argv_with(words: str, option: str, value: str, f: dict, tmp) -> list[str]:
    """A command line of ``words`` that would run, with ``option`` set to ``value``."""
    cam, lay = str(f["camera"]), str(f["layout"])
    base = {
        "calibrate": ["calibrate", "--board", "chessboard:9x6", "--square", "0.025", "--out",
                      str(tmp / "c.yaml"), str(f["images"])],
        "calibrate board": ["calibrate", "board", "--pdf", str(tmp / "b.pdf")],
        "calibrate mount": ["calibrate", "mount", "--camera", cam, "--out",
                            str(tmp / "m.json"), str(f["images"])],
        "run": ["run", "--source", str(f["video"]), "--camera", cam, "--layout", lay,
                "--frames", "1", "--quiet"],
        "serve": ["serve", "--port", str(f["busy_port"])],
        "mission check": ["mission", "check", "wall-2-courses"],
        "mission simulate": ["mission", "simulate", "wall-2-courses", "--record",
                             str(tmp / "rec")],
        "study run": ["study", "run", "--out", str(tmp / "study")],
        "study example": ["study", "example", "--out", str(tmp / "ex")],
    }.get(words) or ["bench", words.split()[1]]
    if option == "--offset":
        return [*base, "--offset", value, "0", "0"]
    return [*base, option, value]


def not_usable(text: str) -> bool:
    """True for text no numeric option accepts (every range here is within ±10⁹)."""
    try:
        v = float(text)
    except (ValueError, OverflowError):
        return True
    return not math.isfinite(v) or abs(v) > 1e10


hostile_numbers = (
    st.sampled_from(["1e20", "9" * 5000, "-" + "9" * 5000, "nan", "NaN", "inf", "-inf",
                     "Infinity", "1e308", "-1e308", "99999999999999", "abc", "", " ", "0x10",
                     "1,5", "\x00", "٣" * 40, "1e20000"])
    | st.integers(min_value=10**11, max_value=10**400).map(str)
    | st.integers(max_value=-10**11, min_value=-10**400).map(str)
    | st.floats(allow_nan=True, allow_infinity=True).filter(
        lambda x: not math.isfinite(x) or abs(x) > 1e10).map(repr)
    | st.text(max_size=12).filter(not_usable)
)


@_settings()
@given(case=st.sampled_from(NUMERIC), value=hostile_numbers)
def test_every_numeric_option_refuses_what_no_command_can_use(cli, hostile_files,
                                                              tmp_path_factory, case, value):
    words, option = case
    tmp = tmp_path_factory.mktemp("argv")
    rc, out, err = cli(*argv_with(words, option, value, hostile_files, tmp),
                       cls="cli argv: numbers", seconds=180)
    assert rc == 2, (words, option, value[:40], err[-400:])
    assert option in err or option.lstrip("-") in err, (words, option, err[-300:])
    assert "Traceback" not in err and "internal error" not in err
    assert not any(tmp.iterdir()), "nothing is written for a refused command"


#: file options of each command: (command words, option or None for a positional INPUT)
FILE_INPUTS = [
    ("detect", "--camera"), ("detect", "--layout"), ("detect", "--gravity-file"),
    ("calibrate mount", "--camera"), ("calibrate mount", "--layout"),
    ("run", "--camera"), ("run", "--layout"), ("run", "--mount"), ("run", "--source"),
    ("serve", "--camera"), ("serve", "--layout"), ("serve", "--mount"), ("serve", "--source"),
    ("serve", "--replay-dir"), ("mission check", None), ("study run", "--protocol"),
]
CONFIG_FILES = {"--camera", "--layout", "--mount", "--protocol", "--gravity-file", None,
                "--replay-dir", "--source"}


def hostile_path(kind: str, f: dict) -> str:
    return {
        "fifo": str(f["fifo"]), "sparse": str(f["sparse"]), "folder": str(f["folder"]),
        "zero": "/dev/zero", "long": str(f["root"] / ("n" * 300 + ".yaml")),
        "nul": str(f["root"]) + "/a\x00b.yaml", "up": "../" * 40 + "etc/passwd",
        "missing": str(f["root"] / "missing.yaml"), "digits": str(f["digits"]),
        "newline": str(f["root"] / "a\nb.yaml"), "proc": "/proc/self/mem",
    }[kind]


PATH_KINDS = ["fifo", "sparse", "folder", "zero", "long", "nul", "up", "missing", "digits",
              "newline", "proc"]


@pytest.mark.parametrize("case", FILE_INPUTS, ids=lambda c: f"{c[0]} {c[1] or 'INPUT'}")
@pytest.mark.parametrize("kind", PATH_KINDS)
def test_every_file_option_refuses_what_is_not_its_file(cli, hostile_files, tmp_path, case,
                                                        kind):
    words, option = case
    if option == "--replay-dir" and kind == "folder":
        pytest.skip("a folder is what --replay-dir takes")
    f = hostile_files
    bad = hostile_path(kind, f)
    cam, lay = str(f["camera"]), str(f["layout"])
    opts = {
        "detect": {"--camera": cam, "--layout": lay, "--gravity-file": None},
        "calibrate mount": {"--camera": cam, "--layout": str(f["pad"])},
        "run": {"--source": str(f["video"]), "--camera": cam, "--layout": lay, "--mount": None},
        "serve": {"--port": str(f["busy_port"]), "--camera": None, "--layout": None, "--mount": None,
                  "--source": None, "--replay-dir": None},
        "study run": {"--protocol": None},
    }.get(words, {})
    opts = {**opts, **({option: bad} if option else {})}
    argv = words.split() + [x for k, v in opts.items() if v is not None for x in (k, v)]
    if words == "detect":
        argv += [str(f["video"])]
    elif words == "calibrate mount":
        argv += ["--out", str(tmp_path / "m.json"), str(f["images"])]
    elif words == "run":
        argv += ["--frames", "1", "--quiet", "--pace", "max"]
    elif words == "mission check":
        argv += [bad]
    elif words == "study run":
        argv += ["--out", str(tmp_path / "study"), "--quick"]
    rc, out, err = cli(*argv, cls="cli argv: files", seconds=180)
    assert "Traceback" not in err and "internal error" not in err, err[-400:]
    if option == "--source" and kind == "sparse":
        # a file named like an image is a one-frame source, checked as an image (never read
        # whole): one that cannot be decoded cannot be opened, refused at start-up
        assert "MiB" in err and "--source" in err, err[-300:]
    assert rc == 2, (argv, err[-400:])
    assert "cannot listen" not in err, "refused for the input, not for the port"
    assert len(err.strip().splitlines()[-1]) < 700


@pytest.mark.parametrize("kind", ["fifo", "sparse", "folder", "zero", "long", "nul",
                                  "missing", "newline"])
def test_detect_reports_an_input_that_is_not_an_image_and_goes_on(cli, hostile_files, kind):
    f = hostile_files
    rc, out, err = cli("detect", "--camera", f["camera"], "--layout", f["layout"],
                       hostile_path(kind, f), cls="cli argv: files")
    assert "Traceback" not in err and "internal error" not in err, err[-400:]
    assert rc in (1, 2), err[-300:]
