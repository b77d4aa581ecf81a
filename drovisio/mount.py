"""The camera mount: where the camera sits on the drone (``body_from_camera``), and the file.

Mount file (JSON or YAML), schema ``drovisio/mount@1``::

    {"schema": "drovisio/mount@1", "body_frame": "FRD",
     "camera": {"tilt_deg": 20, "pan_deg": 0, "roll_deg": 0, "offset_m": [0.08, 0, 0.05]},
     "body_from_camera": [[...4 numbers...], [...], [...], [0, 0, 0, 1]],
     "note": "camera 20° tilted forward, 8 cm ahead and 5 cm below the body origin"}

* ``body_frame``: the drone body frame, FRD (x forward, y right, z down), as MAVLink's
  ``MAV_FRAME_BODY_FRD``.
* ``body_from_camera``: 4×4 rigid transform, ``p_body = body_from_camera @ p_cam`` with the
  camera frame OpenCV's (x right, y down, z forward); metres. Tilt included.
* ``camera`` (the human form, what people measure on the drone; written beside the matrix,
  either is enough, both must agree):

  - ``tilt_deg``: angle of the optical axis away from straight down, toward the nose
    (0: looking straight down; 90: looking forward at the horizon);
  - ``pan_deg``: turn of the camera about the body's down axis, positive to the right
    (clockwise seen from above); 0: the image top points toward the nose;
  - ``roll_deg``: turn of the camera about its own optical axis, positive clockwise as the
    image is seen;
  - ``offset_m``: the camera's centre from the body origin, [forward, right, down], metres.

  ``body_from_camera = Rz(pan) · Ry(tilt) · R_down · Rz(roll)``, with ``R_down`` the camera
  looking straight down, image top forward (x_cam → right, y_cam → back, z_cam → down).

:class:`Mount` turns poses ``camera_from_brick`` into ``body_from_brick`` and gives the
direction of gravity in the camera frame from the vehicle's roll and pitch.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from drovisio.bounds import MOUNT_OFFSET_MAX_M
from drovisio.errors import InputError
from drovisio.geometry import ned_from_body, rot_y, rot_z, transform
from drovisio.textfile import read_structured

__all__ = [
    "MOUNT_SCHEMA",
    "Mount",
    "MountAngles",
    "angles_of",
    "body_from_camera_angles",
    "MountError",
    "MountFile",
    "down_camera_mount",
    "ground_footprint",
    "load_mount",
    "ned_from_body",
]

MOUNT_SCHEMA = "drovisio/mount@1"


class MountError(InputError):
    """A mount file that cannot be used; the message names the file and the field."""


class MountAngles(BaseModel):
    """The mount as people measure it (see the module doc for the conventions)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    tilt_deg: float = Field(ge=0, le=180, description="Optical axis from straight down toward "
                            "the nose, degrees.")
    pan_deg: float = Field(default=0.0, ge=-180, le=180, description="Turn about the body's "
                           "down axis, positive to the right, degrees.")
    roll_deg: float = Field(default=0.0, ge=-180, le=180, description="Turn about the optical "
                            "axis, clockwise in the image, degrees.")
    offset_m: tuple[float, float, float] = Field(
        default=(0.0, 0.0, 0.0), description="Camera centre from the body origin [forward, "
        "right, down], metres.")

    @field_validator("offset_m")
    @classmethod
    def _near(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if max(abs(x) for x in v) > MOUNT_OFFSET_MAX_M:
            raise ValueError(f"offset larger than {MOUNT_OFFSET_MAX_M:g} m: give it in metres")
        return v


class MountFile(BaseModel):
    """The mount file's content (pydantic schema): the matrix, the angles, or both."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True, allow_inf_nan=False)

    schema_id: Literal["drovisio/mount@1"] = Field(alias="schema")
    body_frame: Literal["FRD"] = Field(
        default="FRD", description="Drone body frame: FRD (x forward, y right, z down).")
    camera: MountAngles | None = Field(
        default=None, description="Tilt, pan, roll (degrees) and offset (metres).")
    body_from_camera: list[list[float]] | None = Field(
        default=None,
        description="4×4 rigid transform p_body = body_from_camera · p_cam (metres).")
    note: str | None = Field(default=None, max_length=2000)

    @model_validator(mode="after")
    def _one_form(self) -> MountFile:
        if self.camera is None and self.body_from_camera is None:
            raise ValueError("give 'camera' (tilt_deg, pan_deg, roll_deg, offset_m) or "
                             "'body_from_camera' (4x4)")
        if self.camera is not None and self.body_from_camera is not None:
            a = body_from_camera_angles(**self.camera.model_dump())
            b = np.asarray(self.body_from_camera)
            angle = np.degrees(np.arccos(np.clip((np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2,
                                                 -1, 1)))
            shift = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
            if angle > 0.01 or shift > 1e-4:
                raise ValueError(f"'camera' and 'body_from_camera' disagree by {angle:.2f}° and "
                                 f"{shift * 1000:.1f} mm; keep one of them")
        return self

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
        if np.abs(T[:3, 3]).max() > MOUNT_OFFSET_MAX_M:
            raise ValueError(f"translation larger than {MOUNT_OFFSET_MAX_M:g} m: units must "
                             "be metres")
        return T.tolist()


#: the camera looking straight down, image top toward the nose (x_cam → right, y_cam → back)
BODY_FROM_DOWN_CAMERA = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def body_from_camera_angles(tilt_deg: float, pan_deg: float = 0.0, roll_deg: float = 0.0,
                            offset_m=(0.0, 0.0, 0.0)) -> np.ndarray:
    """``body_from_camera`` (4×4) of the human form (module doc)."""
    R = (rot_z(np.radians(pan_deg)) @ rot_y(np.radians(tilt_deg)) @ BODY_FROM_DOWN_CAMERA
         @ rot_z(np.radians(roll_deg)))
    return transform(R, offset_m)


def angles_of(body_from_camera: np.ndarray) -> dict:
    """The human form (tilt, pan, roll in degrees, offset in metres) of a mount matrix.

    ``R · R_downᵀ = Rz(pan) · Ry(tilt) · Rz(roll)`` (the down camera's roll is a turn about
    the body's z): z-y-z Euler angles, tilt in [0°, 180°]. Looking straight down, pan and roll
    turn the same way; the turn is then reported as roll, pan 0.
    """
    T = np.asarray(body_from_camera, np.float64)
    M = T[:3, :3] @ BODY_FROM_DOWN_CAMERA.T
    tilt = float(np.degrees(np.arccos(np.clip(M[2, 2], -1.0, 1.0))))
    if np.hypot(M[0, 2], M[1, 2]) < 1e-9:
        pan = 0.0
        roll = float(np.degrees(np.arctan2(M[1, 0], M[0, 0])))
    else:
        pan = float(np.degrees(np.arctan2(M[1, 2], M[0, 2])))
        roll = float(np.degrees(np.arctan2(M[2, 1], -M[2, 0])))
    return {"tilt_deg": round(tilt, 6) + 0.0, "pan_deg": round(pan, 6) + 0.0,
            "roll_deg": round(roll, 6) + 0.0,
            "offset_m": [round(float(x), 6) + 0.0 for x in T[:3, 3]]}


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

    @classmethod
    def from_angles(cls, tilt_deg: float, pan_deg: float = 0.0, roll_deg: float = 0.0,
                    offset_m=(0.0, 0.0, 0.0), note: str | None = None) -> Mount:
        """The mount of the human form (module doc)."""
        return cls(body_from_camera_angles(tilt_deg, pan_deg, roll_deg, offset_m), note=note)

    def angles(self) -> dict:
        """The human form: ``{"tilt_deg", "pan_deg", "roll_deg", "offset_m"}``."""
        return angles_of(self.body_from_camera)

    def to_file(self) -> dict:
        """The mount file's content: both forms (people read the angles, programs the
        matrix)."""
        return {"schema": MOUNT_SCHEMA, "body_frame": "FRD", "camera": self.angles(),
                "body_from_camera": self.body_from_camera.tolist(),
                **({"note": self.note} if self.note else {})}


BODY_FROM_ALIGNED_BRICK = np.diag([1.0, -1.0, -1.0])
"""A brick lying flat with its x axis toward the drone's nose: brick (x forward, y left, z up)
→ body FRD (x forward, y right, z down)."""


def measure_mount(camera_from_brick: list[np.ndarray], aligned: bool = False) -> dict:
    """The mount's angles from poses of a code lying flat in view of the drone standing level.

    Gravity in the camera frame is the brick's "down": it gives the tilt and the roll whatever
    the brick's heading (the pan turns about gravity). With the brick's x axis along the
    drone's nose (``aligned``) the pan follows too. Several poses (frames, bricks) are
    averaged on the rotation group.

    Args:
        camera_from_brick: 4×4 poses of bricks lying flat (OpenCV camera frame).
        aligned: The bricks' x axes point toward the drone's nose.

    Returns:
        ``{"tilt_deg", "roll_deg", "pan_deg" (None unless aligned), "spread_deg" (largest
        angle between a single pose's estimate and the mean), "n"}``.
    """
    if not camera_from_brick:
        raise MountError("no code lying flat was found in view: put a shipped code flat on "
                         "the ground in front of the drone")
    Rs = [BODY_FROM_ALIGNED_BRICK @ np.asarray(T, np.float64)[:3, :3].T
          for T in camera_from_brick]
    if not aligned:   # the heading is unknown: each estimate's pan to 0 (about gravity)
        Rs = [rot_z(-np.radians(angles_of(transform(R, (0, 0, 0)))["pan_deg"])) @ R
              for R in Rs]
    U, _, Vt = np.linalg.svd(sum(Rs))          # the chordal mean of the rotations
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    spread = max(float(np.degrees(np.arccos(np.clip((np.trace(R.T @ Ri) - 1) / 2, -1, 1))))
                 for Ri in Rs)
    a = angles_of(transform(R, (0.0, 0.0, 0.0)))
    return {"tilt_deg": a["tilt_deg"], "roll_deg": a["roll_deg"],
            "pan_deg": a["pan_deg"] if aligned else None, "spread_deg": spread,
            "n": len(Rs)}


def ground_footprint(mount: Mount, camera, height_m: float, per_edge: int = 12,
                     max_range_m: float = 30.0) -> dict:
    """Where the camera sees flat ground, the drone level at ``height_m`` above it.

    The image border is sampled (``per_edge`` pixels per side) and each viewing ray (the
    camera's own lens model) is met with the ground plane ``z_body = height_m`` (FRD: z down).
    A ray at or above the horizon is cut at ``max_range_m``.

    Returns:
        ``{"polygon": [[forward, right], ...] (m, body frame), "centre": [f, r] or None (where
        the optical axis meets the ground), "below": bool (the point straight under the body
        origin is in view), "nearest_m", "farthest_m" (ground distance of the footprint from
        under the drone)}``.
    """
    w, h = camera.size
    t = np.linspace(0.0, 1.0, per_edge, endpoint=False)
    border = np.concatenate([
        np.stack([t * (w - 1), np.zeros_like(t)], 1),
        np.stack([np.full_like(t, w - 1.0), t * (h - 1)], 1),
        np.stack([(1 - t) * (w - 1), np.full_like(t, h - 1.0)], 1),
        np.stack([np.zeros_like(t), (1 - t) * (h - 1)], 1)])
    R, c = mount.body_from_camera[:3, :3], mount.body_from_camera[:3, 3]

    def meet(rays_cam: np.ndarray) -> np.ndarray:
        d = rays_cam @ R.T
        down = height_m - c[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(d[:, 2] > 1e-9, down / d[:, 2], np.inf)
        horiz = np.linalg.norm(d[:, :2], axis=1)
        s = np.minimum(s, np.where(horiz > 1e-12, max_range_m / np.maximum(horiz, 1e-12),
                                   np.inf))
        return c[:2] + d[:, :2] * s[:, None]

    rays = camera.rays(border)
    with np.errstate(all="ignore"):  # extreme lenses: rays that are not numbers are dropped
        down_part = (rays @ R.T)[:, 2]
        poly = meet(rays)
    finite = np.isfinite(poly).all(axis=1)
    dropped = int((~finite).sum())
    poly = poly[finite]
    axis = R[:, 2]
    centre = None
    if axis[2] > 1e-9:
        centre = (c[:2] + axis[:2] * (height_m - c[2]) / axis[2]).tolist()
        if not np.isfinite(centre).all():
            centre = None
    # straight below the body origin: in view when it projects inside the image
    below_cam = mount.camera_from_body @ np.array([0.0, 0.0, height_m, 1.0])
    inside = False
    if below_cam[2] > 1e-9:
        with np.errstate(all="ignore"):
            uv = camera.project(below_cam[None, :3])[0]
        inside = bool(np.isfinite(uv).all() and 0 <= uv[0] <= w - 1 and 0 <= uv[1] <= h - 1)
    dist = np.linalg.norm(poly, axis=1)
    out = {"polygon": np.round(poly, 4).tolist(),
           "centre": None if centre is None else [round(float(v), 4) for v in centre],
           "below": inside,
           "nearest_m": 0.0 if inside or not len(dist) else round(float(dist.min()), 3),
           "farthest_m": round(float(dist.max()), 3) if len(dist) else 0.0,
           # no ray of the picture's border goes down: the camera sees sky, not ground
           "sees_ground": bool(np.any(down_part > 1e-9)),
           # part of the picture is at or above the horizon (its rays cut at max_range_m)
           "horizon": bool(np.any(~(down_part > 1e-9))
                           or (len(dist) > 0 and float(dist.max()) >= max_range_m - 1e-6))}
    if dropped:  # the domain says so rather than sending numbers that are not JSON
        out["note"] = (f"{dropped} of {len(finite)} border rays of this camera file give no "
                       "point on the ground (its lens coefficients are extreme); check the "
                       "camera file")
    return out


def down_camera_mount() -> Mount:
    """Camera looking straight down, image top toward the drone's front, at the body origin."""
    return Mount.from_angles(0.0, note="camera looking down, image top forward")


def load_mount(path: str | os.PathLike) -> Mount:
    """Read a mount file (JSON or YAML)."""
    p = Path(path)
    try:
        data = read_structured(p, "mount file")
    except InputError as e:
        raise MountError(str(e)) from None
    if not isinstance(data, dict):
        raise MountError(f"{p}: expected a mapping with 'schema' and 'body_from_camera'")
    try:
        mf = MountFile.model_validate(data)
    except ValidationError as e:
        errs = "; ".join(f"{'.'.join(str(x) for x in err['loc']) or '(file)'}: {err['msg']}"
                         for err in e.errors()[:5])
        raise MountError(f"{p}: {errs}") from None
    T = (np.asarray(mf.body_from_camera) if mf.body_from_camera is not None
         else body_from_camera_angles(**mf.camera.model_dump()))  # type: ignore[union-attr]
    return Mount(T, note=mf.note, source=str(p))
