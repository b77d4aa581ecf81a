"""``drovisio station``: the ground station's arguments. Its code is
:func:`webtool.serve.run_station` (the web stack is loaded only when the command runs)."""

from __future__ import annotations

import argparse

from drovisio.arguments import Command
from drovisio.bounds import whole
from drovisio.commands.serve import add_web_arguments
from drovisio.zenoh_endpoint import ENDPOINT_HELP, endpoint_problem

__all__ = ["COMMAND", "add_arguments", "zenoh_endpoint"]


def zenoh_endpoint(text: str) -> str:
    """argparse type: a Zenoh endpoint ``tcp/HOST:PORT``."""
    problem = endpoint_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(f"{text[:80]!r} {problem}: {ENDPOINT_HELP}")
    return text


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", type=zenoh_endpoint, action="append", metavar="ENDPOINT",
                   help="where drones connect (repeatable; default tcp/0.0.0.0:7447: every "
                        "address of this machine)")
    p.add_argument("--connect", type=zenoh_endpoint, action="append", metavar="ENDPOINT",
                   help="also connect to a Zenoh router or to drones that listen "
                        "(repeatable)")
    p.add_argument("--domain", type=whole(0, 232), default=0, metavar="N",
                   help="ROS domain id of the drones' keys (default 0)")
    add_web_arguments(p, of=" of the web tool")
    p.add_argument("--data", metavar="DIR",
                   help="this station's data folder (default: $DROVISIO_DATA, else "
                        "~/.local/share/drovisio)")


COMMAND = Command(
    name="station",
    summary="the ground station: every drone of the site on one Fleet page",
    description="Listen for the drones of a site over Zenoh (each runs drovisio run or serve "
                "with --drone-id ID --sink zenoh:connect=tcp/STATION:7447) and serve the web "
                "tool with a Fleet page: every drone live or lost, its frame rate, latency, "
                "bricks and target, a camera thumbnail, a link to its own web tool, and all "
                "drones' bricks in one 3D view. Same access rules as drovisio serve.",
    example="drovisio station\n"
            "  drovisio station --host 0.0.0.0 --listen tcp/0.0.0.0:7447\n"
            "  drovisio run --source 0 --camera camera.yaml --layout L.json --drone-id drone1 "
            "\\\n      --sink zenoh:connect=tcp/192.168.1.10:7447   # on each drone",
    add_arguments=add_arguments,
    target="webtool.serve:run_station",
)
