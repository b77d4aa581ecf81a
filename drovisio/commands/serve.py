"""``drovisio serve``: the web tool's arguments. Its code is :func:`webtool.serve.run` (the web
stack is loaded only when the command runs)."""

from __future__ import annotations

import argparse

from drovisio.arguments import Command, port_number
from drovisio.commands.run import add_pipeline_arguments

__all__ = ["COMMAND", "add_arguments", "add_web_arguments"]

# --------------------------------------------------------------------------------------------
# The command line
# --------------------------------------------------------------------------------------------


def add_web_arguments(p: argparse.ArgumentParser, of: str = "") -> None:
    """``--host`` and ``--port`` of a web tool's server (``serve``, ``station``); ``of``
    names the server where the command listens for something else too."""
    p.add_argument("--host", default="127.0.0.1",
                   help=f"address{of} to listen on (default: 127.0.0.1, this machine only; any "
                        "other address turns on token access)")
    p.add_argument("--port", type=port_number, default=8080,
                   help=f"port{of} to listen on (default: 8080)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``drovisio serve``'s arguments: the server's, then the pipeline of its live page."""
    add_web_arguments(p)
    p.add_argument("--source", metavar="SOURCE",
                   help="camera index, video file, folder of images or stream URL "
                        "(default: the built-in sample session)")
    p.add_argument("--camera", metavar="CAMERA_FILE", help="camera file")
    add_pipeline_arguments(p, serving=True)
    p.add_argument("--data", metavar="DIR",
                   help="this server's data folder: calibration, mount, saved layouts and "
                        "study reports (default: $DROVISIO_DATA, else "
                        "~/.local/share/drovisio); never the checkout")
    p.add_argument("--replay-dir", metavar="DIR",
                   help="folder of mission recordings (drovisio mission simulate --record) to "
                        "replay in 3D on the live page (default: the sample mission)")


COMMAND = Command(
    name="serve",
    summary="serve the web tool (calibration, marker designer, live view)",
    description="Serve the browser tool used in the field: camera calibration, marker "
                "design on a brick's 3D mesh, and live detections. With no --source it "
                "runs on the built-in sample session. The default host 127.0.0.1 is "
                "reachable from this machine only; binding any other address (e.g. "
                "0.0.0.0 for a tablet on the drone's Wi-Fi) turns on token access: open "
                "the printed URL, which carries the token.",
    example="drovisio serve\n"
            "  drovisio serve --host 0.0.0.0 --port 8080 --source 0 --camera camera.yaml\n"
            "  drovisio serve --host 0.0.0.0 --source 0 --camera camera.yaml "
            "--mount mount.json \\\n"
            "      --layout marker_layouts/drick-aruco-pyramids.json "
            "--sink mavlink:/dev/ttyAMA0,921600",
    add_arguments=add_arguments,
    target="webtool.serve:run",
)
