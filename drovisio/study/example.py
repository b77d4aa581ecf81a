"""A recorded-style example: renders of a few steps written as videos and as a folder of
images, with the protocol that maps them to their truth, as a user's own recordings would be.
``drovisio study example --out DIR`` writes it; the sample data ships one
(``sample_sessions/study``)."""

from __future__ import annotations

from pathlib import Path

import cv2
import yaml

from drovisio.camera import Camera
from drovisio.fileio import atomic_write_text, write_image, write_video
from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.study.frames import step_frames
from drovisio.study.protocol import PROTOCOL_SCHEMA, Step

__all__ = ["write_recorded_example"]

STEPS = [("6.7", "code", "distance", 0.6, "code_60cm.mp4"),
         ("6.7", "code", "distance", 1.2, "code_120cm.mp4"),
         ("6.9", "code", "rot_z", 45.0, "code_rotz45"),          # a folder of images
         ("6.3", "dots", "distance", 1.0, "dots_100cm.mp4")]


def write_recorded_example(out: Path, frames: int = 6) -> Path:
    """Write the example into ``out`` (videos, an image folder, ``protocol.yaml``)."""
    out.mkdir(parents=True, exist_ok=True)
    cam = Camera.drone_webcam()
    names = {"code": "drick-aruco-centre", "dots": "drick-dots-2x3"}
    steps = []
    for i, (fig, lay, vary, value, src) in enumerate(STEPS):
        step = Step(figure=fig, layout=lay, vary=vary, value=value, frames=frames)
        layout = load_layout(shipped_layouts_dir() / f"{names[lay]}.json")
        imgs = [f.image for f in step_frames(step, layout, cam, 900 + i, out)]
        if src.endswith(".mp4"):   # beside, checked, renamed: an old video survives a full disk
            write_video(out / src, imgs, 10.0, (cam.width, cam.height))
        else:
            (out / src).mkdir(exist_ok=True)
            for k, img in enumerate(imgs):
                write_image(out / src / f"frame_{k:03d}.jpg", img,
                            [cv2.IMWRITE_JPEG_QUALITY, 92])
        steps.append({**step.model_dump(exclude_none=True), "source": src})
    protocol = {"schema": PROTOCOL_SCHEMA, "name": "recorded example",
                "layouts": [{"name": k, "layout": v} for k, v in names.items()],
                "steps": steps}
    path = out / "protocol.yaml"
    atomic_write_text(path, "# Renders written as recordings: each step names its video or "
                      "folder and the set-up\n# it was recorded in (the truth).\n"
                      + yaml.safe_dump(protocol, sort_keys=False))
    return path
