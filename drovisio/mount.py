"""The camera mount: where the camera sits on the drone (``body_from_camera``), and the file.

Mount file (JSON or YAML), schema ``drovisio/mount@1``::

    {"schema": "drovisio/mount@1", "body_frame": "FRD",
     "body_from_camera": [[...4 numbers...], [...], [...], [0, 0, 0, 1]],
     "note": "camera 20° tilted forward, 8 cm ahead and 5 cm below the body origin"}

* ``body_frame``: the drone body frame, FRD (x forward, y right, z down), as MAVLink's
  ``MAV_FRAME_BODY_FRD``.
* ``body_from_camera``: 4×4 rigid transform, ``p_body = body_from_camera @ p_cam`` with the
  camera frame OpenCV's (x right, y down, z forward); metres. Tilt included.

:class:`Mount` turns poses ``camera_from_brick`` into ``body_from_brick`` and gives the
direction of gravity in the camera frame from the vehicle's roll and pitch.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from drovisio.geometry import ned_from_body

__all__ = [
    "MOUNT_SCHEMA",
    "Mount",
    "MountError",
    "MountFile",
    "down_camera_mount",
    "load_mount",
    "ned_from_body",
]

MOUNT_SCHEMA = "drovisio/mount@1"


class MountError(ValueError):
    """A mount file that cannot be used; the message names the file and the field."""


class MountFile(BaseModel):
    """The mount file's content (pydantic schema)."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True, allow_inf_nan=False)

    schema_id: Literal["drovisio/mount@1"] = Field(alias="schema")
    body_frame: Literal["FRD"] = Field(
        default="FRD", description="Drone body frame: FRD (x forward, y right, z down).")
    body_from_camera: list[list[float]] = Field(
        description="4×4 rigid transform p_body = body_from_camera · p_cam (metres).")
    note: str | None = None

    @field_validator("body_from_camera")
    @classmethod
    def _rigid(cls, v: list[list[float]]) -> list[list[float]]:
        T = np.asarray(v, dtype=np.float64)
        if T.shape == (3, 4):
            T = np.vstack([T, [0.0, 0.0, 0.0, 1.0]])
        if T.shape != (4, 4):
            raise ValueError(f"must be a 4×4 matrix (rows of 4 numbers), got shape {T.shape}")
        if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
            raise ValueError("last row must be [0, 0, 0, 1]")
        R = T[:3, :3]
        err = float(np.abs(R.T @ R - np.eye(3)).max())
        if err > 1e-4:
            raise ValueError(f"rotation part is not orthonormal (max |RᵀR − I| = {err:.2g})")
        if np.linalg.det(R) < 0:
            raise ValueError("rotation part is a reflection (det < 0)")
        if np.abs(T[:3, 3]).max() > 10:
            raise ValueError("translation larger than 10 m: units must be metres")
        return T.tolist()


class Mount:
    """A rigid camera mount on the drone body (FRD)."""

    def __init__(self, body_from_camera: np.ndarray, note: str | None = None,
                 source: str | None = None):
        T = np.asarray(body_from_camera, np.float64).reshape(4, 4).copy()
        # re-orthonormalise (files hold rounded numbers)
        U, _, Vt = np.linalg.svd(T[:3, :3])
        T[:3, :3] = U @ Vt
        self.body_from_camera = T
        self.camera_from_body = np.linalg.inv(T)
        self.note = note
        self.source = source

    def body_from(self, camera_from_x: np.ndarray) -> np.ndarray:
        """``body_from_x = body_from_camera @ camera_from_x`` (4×4)."""
        return self.body_from_camera @ camera_from_x

    def point_in_body(self, p_cam: np.ndarray) -> np.ndarray:
        return self.body_from_camera[:3, :3] @ np.asarray(p_cam, np.float64).ravel() \
            + self.body_from_camera[:3, 3]

    def gravity_in_camera(self, roll: float = 0.0, pitch: float = 0.0) -> np.ndarray:
        """Unit vector of gravity (down) in the camera frame for a vehicle at roll/pitch (rad).

        Level flight (roll = pitch = 0) gives the mount's own "down": a good prior for the
        detectors' flip decision even without an attitude from the autopilot.
        """
        g_ned = np.array([0.0, 0.0, 1.0])
        g_body = ned_from_body(roll, pitch, 0.0).T @ g_ned
        g = self.camera_from_body[:3, :3] @ g_body
        return g / np.linalg.norm(g)

    def to_file(self) -> dict:
        return {"schema": MOUNT_SCHEMA, "body_frame": "FRD",
                "body_from_camera": self.body_from_camera.tolist(),
                **({"note": self.note} if self.note else {})}


def down_camera_mount() -> Mount:
    """Camera looking straight down, image top toward the drone's front, at the body origin."""
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = R
    return Mount(T, note="camera looking down, image top forward")


def load_mount(path: str | os.PathLike) -> Mount:
    """Read a mount file (JSON or YAML)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise MountError(f"{p}: cannot read the mount file ({e.strerror or e})") from e
    try:
        data = json.loads(text) if p.suffix.lower() == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as e:
        raise MountError(f"{p}: not valid {'JSON' if p.suffix.lower() == '.json' else 'YAML'}"
                         f": {e}") from e
    if not isinstance(data, dict):
        raise MountError(f"{p}: expected a mapping with 'schema' and 'body_from_camera'")
    try:
        mf = MountFile.model_validate(data)
    except ValidationError as e:
        errs = "; ".join(f"{'.'.join(str(x) for x in err['loc']) or '(file)'}: {err['msg']}"
                         for err in e.errors())
        raise MountError(f"{p}: {errs}") from e
    return Mount(np.asarray(mf.body_from_camera), note=mf.note, source=str(p))
