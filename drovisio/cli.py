"""The ``drovisio`` command line: the top-level parser, the command registry and the one
place every error is handled.

Each command module of :mod:`drovisio.commands` declares its own arguments, help and example
(``COMMAND``, the contract of DESIGN.md) beside its code; ``COMMANDS`` lists them in the order
``drovisio --help`` shows them. A command's code is imported only when it runs (its
``"module:function"`` entry point), so that ``drovisio --help`` stays fast (no OpenCV, no web
stack).

Every error is handled once, here: bad input (:class:`~drovisio.errors.InputError`, and
:class:`~drovisio.errors.WriteError` for a file that could not be written) prints one line
``drovisio COMMAND: FILE: FIELD: what to do`` and exits 2; anything unexpected prints one line
and the path of a file holding the full traceback (``--debug`` prints it instead) and exits 1.
A closed output pipe (``drovisio detect ... | head -1``) ends the command quietly.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Sequence
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from drovisio.arguments import (  # re-exported: the benches and tests used them from here
    PROG,
    Command,
    board_square,
    drone_id,
    finite_float,
    mount_offset,
    nonnegative_float,
    plain_help,
    port_number,
    positive_float,
    positive_int,
    seed_number,
    supersampling,
)
from drovisio.bounds import ArgumentParser
from drovisio.commands import (
    autopilot,
    bench,
    calibrate,
    detect,
    mission,
    run,
    serve,
    station,
    study,
    synth,
)
from drovisio.errors import InputError, WriteError, limit_message, one_line
from drovisio.fileio import atomic_write_text, guard_outputs

__all__ = [
    "COMMANDS",
    "Command",
    "board_square",
    "build_command_parser",
    "build_parser",
    "drone_id",
    "finite_float",
    "main",
    "mount_offset",
    "nonnegative_float",
    "one_line",
    "plain_help",
    "port_number",
    "positive_float",
    "positive_int",
    "resolve",
    "seed_number",
    "supersampling",
]

EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 1
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a writer whose reader left

COMMANDS: dict[str, Command] = {
    c.name: c
    for c in [detect.COMMAND, calibrate.COMMAND, calibrate.BOARD_COMMAND,
              calibrate.MOUNT_COMMAND, run.COMMAND, serve.COMMAND, bench.COMMAND,
              station.COMMAND, study.COMMAND, mission.COMMAND, autopilot.COMMAND, synth.COMMAND]
}


def _version() -> str:
    try:
        return version("drovisio")
    except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        return "0+unknown"


# --------------------------------------------------------------------------------------------
# Parser and dispatch
# --------------------------------------------------------------------------------------------


def _sub_commands() -> list[str]:
    """Every ``COMMAND ACTION`` of the parser (sub-parsers and benchmark names), for the
    top-level help."""
    out: list[str] = []
    for cmd in COMMANDS.values():
        if cmd.spelled:
            continue
        if cmd.name == "bench":
            out.append(f"bench {'|'.join(bench.BENCHMARKS)}")
            continue
        p = build_command_parser(cmd)
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                out.append(f"{cmd.name} {'|'.join(a.choices)}")
    return out


def unknown_command(word: str) -> str:
    """The line for a first word that names no command: the commands users type (those of
    ``drovisio --help``; never the internal names the two-word actions are parsed as), and
    the nearest one when it is close."""
    import difflib  # deferred: only a mistyped command needs it

    typed = {(c.spelled or c.name): c for c in COMMANDS.values()}
    near = difflib.get_close_matches(word.replace("-", " ").lower(), list(typed), n=1)
    listed = ", ".join(c.name for c in COMMANDS.values() if not c.spelled)
    hint = f"did you mean '{near[0]}'? " if near else ""
    return f"unknown command {one_line(repr(word), 60)}; {hint}the commands are {listed}"


class _TopParser(ArgumentParser):
    """The top-level parser: an unknown command is said by :func:`unknown_command` (argparse
    would list every sub-parser's name, internal ones included)."""

    def _check_value(self, action: argparse.Action, value: object) -> None:
        if isinstance(action, argparse._SubParsersAction) and value not in action.choices:
            raise argparse.ArgumentError(None, unknown_command(str(value)))
        super()._check_value(action, value)


def build_command_parser(cmd: Command) -> argparse.ArgumentParser:
    """One command's parser on its own (no help option), as listed in the top-level help."""
    p = ArgumentParser(prog=f"{PROG} {cmd.spelled or cmd.name}", add_help=False)
    cmd.add_arguments(p)
    return p


def build_parser() -> argparse.ArgumentParser:
    """The ``drovisio`` parser: the top-level options and one sub-parser per command."""
    parser = _TopParser(
        prog=PROG,
        description="Drovisio: local positioning for builder drones.\n"
                    "Finds bricks by their colour dots or ArUco codes and gives each brick's "
                    "6-DoF pose.",
        epilog="Sub-commands:\n  " + "\n  ".join(_sub_commands()) + "\n\n"
               "Example:\n  drovisio serve          # then open the printed URL\n"
               "Run `drovisio COMMAND --help` (e.g. `drovisio calibrate mount --help`) for a "
               "command's options and an example.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    parser.add_argument("--debug", action="store_true",
                        help="print the full traceback of an unexpected error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands",
                                parser_class=ArgumentParser)
    for cmd in COMMANDS.values():
        p = sub.add_parser(
            cmd.name,
            prog=f"{PROG} {cmd.spelled or cmd.name}",
            help=cmd.summary,
            description=cmd.description,
            epilog=f"Example:\n  {cmd.example}",
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        if cmd.spelled:     # listed as people type it ("calibrate board")
            sub._choices_actions[-1].metavar = cmd.spelled
        cmd.add_arguments(p)
    return parser


def resolve(entry_point: str) -> Callable[[argparse.Namespace], int | None]:
    """The function of a ``"module:function"`` entry point."""
    module_name, _, func_name = entry_point.partition(":")
    module = importlib.import_module(module_name)
    return getattr(module, func_name or "run")


def _crash_report(command: str, exc: BaseException) -> str | None:
    """Write the traceback of an unexpected error to a file; its path, or None."""
    text = "".join(traceback.format_exception(exc))
    name = f"drovisio-{command}-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.txt"
    path = Path(tempfile.gettempdir()) / name
    try:
        # never over an existing name: in a shared /tmp it may be another user's symlink
        atomic_write_text(path, f"drovisio {_version()} {command}\n{' '.join(sys.argv)}\n\n"
                                f"{text}", overwrite=False, mode=0o600)
    except OSError:
        return None
    return str(path)


def _say(label: str, message: str) -> None:
    try:
        print(f"{label}: {one_line(message, 600)}", file=sys.stderr, flush=True)
    except (OSError, ValueError):  # stderr itself is gone
        pass


def _quiet_stdout() -> None:
    """After a broken pipe, point stdout at /dev/null so the interpreter's final flush does
    not raise again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _exit_code(exc: SystemExit) -> int:
    """The status a parser's ``SystemExit`` carries (--help: 0, a usage error: 2)."""
    return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)


def _spelled_as_typed(argv: list[str]) -> list[str]:
    """``calibrate board`` and ``calibrate mount`` as the commands they name (a folder named
    ``board`` or ``mount`` stays an image folder of ``calibrate``)."""
    if argv[:2] == ["calibrate", "board"] and any(
            a in ("--pdf", "-h", "--help") or a.startswith("--pdf=") for a in argv[2:]):
        return ["calibrate-board", *argv[2:]]     # printing the board, not calibrating
    if argv[:2] == ["calibrate", "mount"] and "--board" not in argv:
        return ["calibrate-mount", *argv[2:]]     # the mount, not the lens
    return argv


def _unexpected(label: str, command: str, e: Exception) -> int:
    """Say an error nobody expected in one line (its traceback in a file); the exit status."""
    limit = limit_message(e)
    if limit is not None:  # an OS or Python limit reached by the input: bad input
        _say(label, limit)
        return EXIT_BAD_INPUT
    where = _crash_report(command, e)
    _say(label, f"internal error: {type(e).__name__}: {e}"
                + (f" (full traceback in {where}; --debug prints it; please report it)"
                   if where else " (run with --debug for the traceback)"))
    return EXIT_INTERNAL


def _dispatch(args: argparse.Namespace, label: str, debug: bool) -> int:
    """Run the parsed command; every error it raises becomes one line and an exit status."""
    try:
        guard_outputs(args)
        func = resolve(COMMANDS[args.command].entry_point)
        result = func(args)
    except KeyboardInterrupt:
        return 130
    except SystemExit as exc:  # a benchmark's own parser: its usage line is said already
        return _exit_code(exc)
    except BrokenPipeError:
        _quiet_stdout()
        return EXIT_BROKEN_PIPE
    except (InputError, WriteError) as e:
        if debug:
            raise
        _say(label, str(e))
        return EXIT_BAD_INPUT
    except Exception as e:  # noqa: BLE001 - the one place that reports what nobody expected
        if debug:
            raise
        return _unexpected(label, args.command, e)
    return int(result or 0)


def main(argv: Sequence[str] | None = None) -> int:
    """``drovisio ARGS``: the exit status (0 done, 1 unexpected error or failed check,
    2 bad input)."""
    parser = build_parser()
    argv = _spelled_as_typed(list(sys.argv[1:] if argv is None else argv))
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors: return, don't exit
        return _exit_code(exc)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    args.argv_tail = argv[2:] if args.command == "study" else argv[1:]
    label = f"{PROG} {COMMANDS[args.command].spelled or args.command}"
    debug = args.debug or os.environ.get("DROVISIO_DEBUG", "") not in ("", "0")
    return _dispatch(args, label, debug)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
