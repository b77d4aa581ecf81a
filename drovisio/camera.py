"""Calibrated pinhole camera with Brown distortion, and the camera-file contract.

Conventions (DESIGN.md):
    * Camera frame: OpenCV's (x right, y down, z forward), metres.
    * Pixel (0, 0) is the centre of the top-left pixel.
    * Distortion: OpenCV's coefficient vector (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tx ty]]]]),
      so 4, 5, 8, 12 and 14 coefficients are all accepted, as ``cv2.calibrateCamera`` writes them.

Files read: OpenCV FileStorage YAML/XML/JSON with ``camera_matrix`` and
``distortion_coefficients`` (and optionally ``image_width``/``image_height``), and ROS
``camera_info`` YAML. Files written: the OpenCV form by default, ROS or JSON on request, at
full double precision (a write-read round trip is exact to 1e-12 relative).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import yaml

__all__ = ["Camera", "CameraFileError", "load_camera", "save_camera"]

_VALID_DIST_LENGTHS = (4, 5, 8, 12, 14)
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)

CameraFormat = Literal["opencv", "ros", "json"]


class CameraFileError(ValueError):
    """A camera file that cannot be used; the message names the file, the field and the fix."""


@dataclass(frozen=True)
class Camera:
    """Intrinsics, Brown distortion and image size of a calibrated camera.

    Args:
        K: 3×3 camera matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]] in pixels.
        dist: OpenCV distortion coefficients (4, 5, 8, 12 or 14 values).
        width: Image width in pixels the intrinsics belong to.
        height: Image height in pixels.
        name: Free-form camera name (kept in ROS files).
    """

    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width: int = 640
    height: int = 480
    name: str = "camera"

    def __post_init__(self) -> None:
        K = np.array(self.K, dtype=np.float64).reshape(3, 3)
        dist = np.array(self.dist, dtype=np.float64).ravel()
        if dist.size not in _VALID_DIST_LENGTHS:
            raise ValueError(
                f"distortion has {dist.size} coefficients; OpenCV uses 4, 5, 8, 12 or 14")
        K.flags.writeable = False
        dist.flags.writeable = False
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # ----------------------------------------------------------------------------- builders
    @classmethod
    def from_fov(cls, width: int = 640, height: int = 480, hfov_deg: float = 60.0,
                 dist: np.ndarray | list[float] | None = None, name: str = "camera") -> "Camera":
        """A camera with square pixels, centred principal point and the given horizontal FOV.

        Args:
            width: Image width in pixels.
            height: Image height in pixels.
            hfov_deg: Horizontal field of view in degrees (of the pinhole part).
            dist: Distortion coefficients; zeros if omitted.
            name: Camera name.
        """
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0, 0, 1.0]])
        return cls(K=K, dist=np.zeros(5) if dist is None else np.asarray(dist, float),
                   width=width, height=height, name=name)

    @classmethod
    def drone_webcam(cls) -> "Camera":
        """The thesis's drone camera: a 60° webcam at 640×480 with mild barrel distortion."""
        cam = cls.from_fov(640, 480, 60.0, dist=[-0.12, 0.08, 0.0006, -0.0004, -0.02],
                           name="drone-webcam-60")
        K = cam.K.copy()
        K[0, 2] += 3.7  # a real lens is never exactly centred
        K[1, 2] -= 2.1
        K[1, 1] *= 1.002
        return cls(K=K, dist=cam.dist, width=640, height=480, name=cam.name)

    # ----------------------------------------------------------------------------- accessors
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels, OpenCV's order."""
        return (self.width, self.height)

    def hfov_deg(self) -> float:
        """Horizontal field of view of the pinhole part, degrees."""
        return math.degrees(2 * math.atan2(self.width / 2.0, self.fx))

    def scaled(self, width: int, height: int) -> "Camera":
        """The same camera at another resolution (same sensor, resampled).

        Pixel centres map as x' = (x + 0.5)·sx − 0.5, so the principal point moves with them;
        distortion acts on normalised coordinates and does not change.
        """
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0, 0] *= sx
        K[0, 1] *= sx
        K[1, 1] *= sy
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        return Camera(K=K, dist=self.dist.copy(), width=width, height=height, name=self.name)

    def almost_equal(self, other: "Camera", rtol: float = 1e-12) -> bool:
        """True when the two cameras agree to ``rtol`` relative (distortion padded with zeros)."""
        n = max(self.dist.size, other.dist.size)
        d1 = np.pad(self.dist, (0, n - self.dist.size))
        d2 = np.pad(other.dist, (0, n - other.dist.size))
        return (self.size == other.size and np.allclose(self.K, other.K, rtol=rtol, atol=0)
                and np.allclose(d1, d2, rtol=rtol, atol=1e-300))

    # ----------------------------------------------------------------------------- geometry
    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Project camera-frame points (N, 3) in metres to distorted pixels (N, 2)."""
        pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 1, 3)
        if pts.shape[0] == 0:
            return np.zeros((0, 2))
        px, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), self.K, self.dist)
        return px.reshape(-1, 2)

    def project_from(self, points: np.ndarray, camera_from_object: np.ndarray) -> np.ndarray:
        """Project object-frame points (N, 3) through a 4×4 ``camera_from_object`` transform."""
        T = np.asarray(camera_from_object, dtype=np.float64)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return self.project(pts @ T[:3, :3].T + T[:3, 3])

    def normalize(self, pixels: np.ndarray) -> np.ndarray:
        """Undistort pixels (N, 2) to normalised image coordinates (x/z, y/z), (N, 2).

        Uses OpenCV's iterative undistortion with a tight criterion, then Newton steps where
        it has not converged, so that re-projecting the result gives back the pixel to ~1e-9
        px. Pixels that no ray reaches (beyond the radius where a strong distortion
        polynomial folds back) come out as NaN.
        """
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        if px.shape[0] == 0:
            return np.zeros((0, 2))
        xy = cv2.undistortPoints(px, self.K, self.dist, None, np.eye(3), np.eye(3),
                                 _UNDISTORT_CRITERIA).reshape(-1, 2)
        if self.dist.size <= 12 and np.any(self.dist):
            xy = self._polish(xy, px.reshape(-1, 2))
        return xy

    def _polish(self, xy: np.ndarray, px: np.ndarray, steps: int = 4) -> np.ndarray:
        """Newton steps on distort(x) = target where OpenCV's fixed-point iteration has not
        converged (it can stall near strongly distorted image corners)."""
        Kinv = np.linalg.inv(self.K)
        target = px @ Kinv[:2, :2].T + Kinv[:2, 2]  # distorted normalised coordinates
        bad = np.nonzero(np.abs(_distort(xy, self.dist) - target).max(axis=1) > 1e-13)[0]
        if bad.size == 0:
            return xy
        xy = xy.copy()
        sub, tgt = xy[bad], target[bad]
        h = 1e-7
        for _ in range(steps):
            f = _distort(sub, self.dist) - tgt
            jx = (_distort(sub + [h, 0], self.dist) - _distort(sub - [h, 0], self.dist)) / (2 * h)
            jy = (_distort(sub + [0, h], self.dist) - _distort(sub - [0, h], self.dist)) / (2 * h)
            det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
            det = np.where(np.abs(det) < 1e-12, 1e-12, det)
            dx = (jy[:, 1] * f[:, 0] - jy[:, 0] * f[:, 1]) / det
            dy = (-jx[:, 1] * f[:, 0] + jx[:, 0] * f[:, 1]) / det
            sub = sub - np.stack([dx, dy], axis=1)
        # pixels beyond the radius where the distortion polynomial folds back have no ray
        residual = np.abs(_distort(sub, self.dist) - tgt).max(axis=1)
        sub[~(residual < 1e-9)] = np.nan
        xy[bad] = sub
        return xy

    def undistort_points(self, pixels: np.ndarray) -> np.ndarray:
        """Undistort pixels (N, 2) to the pixels of the same camera without distortion."""
        xy = self.normalize(pixels)
        return xy @ self.K[:2, :2].T + self.K[:2, 2]

    def rays(self, pixels: np.ndarray) -> np.ndarray:
        """Unit viewing rays (N, 3) in the camera frame through the given pixels."""
        xy = self.normalize(pixels)
        r = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
        return r / np.linalg.norm(r, axis=1, keepdims=True)

    # ----------------------------------------------------------------------------- files
    @classmethod
    def load(cls, path: str | os.PathLike) -> "Camera":
        """Read a camera file (see :func:`load_camera`)."""
        return load_camera(path)

    def save(self, path: str | os.PathLike, fmt: CameraFormat | None = None) -> Path:
        """Write this camera (see :func:`save_camera`)."""
        return save_camera(self, path, fmt)


def _distort(xy: np.ndarray, d: np.ndarray) -> np.ndarray:
    """OpenCV's distortion of normalised coordinates (N, 2), for up to 12 coefficients."""
    c = np.zeros(12)
    c[: d.size] = d[:12]
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = c
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    radial = (1 + k1 * r2 + k2 * r4 + k3 * r6) / (1 + k4 * r2 + k5 * r4 + k6 * r6)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r4
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r4
    return np.stack([xd, yd], axis=1)


# ================================================================================ reading
def load_camera(path: str | os.PathLike) -> Camera:
    """Read an OpenCV FileStorage (YAML, XML, JSON) or ROS ``camera_info`` YAML camera file.

    Args:
        path: The camera file.

    Returns:
        The camera. When the file has no image size, 640×480 is *not* assumed silently:
        width/height come from ``2·cx + 1`` rounded, the best guess for a centred lens.

    Raises:
        CameraFileError: The file is missing, unreadable, or a field is absent or malformed;
            the message names the file and the field.
    """
    p = Path(path)
    if not p.exists():
        raise CameraFileError(f"{p}: camera file not found (give the path of a calibration "
                              "file written by 'drovisio calibrate' or OpenCV/ROS)")
    if p.is_dir():
        raise CameraFileError(f"{p}: is a folder; give the camera file itself")
    try:
        text = p.read_text(encoding="utf-8", errors="strict")
    except (UnicodeDecodeError, OSError) as e:
        raise CameraFileError(f"{p}: cannot read as text ({e}); a camera file is YAML, XML "
                              "or JSON") from None
    head = text.lstrip()[:200]
    if head.startswith("%YAML") or head.startswith("<?xml") or head.startswith("<opencv"):
        return _load_opencv(p)
    if head.startswith("{"):
        try:
            data = json.loads(text)
        except json.JSONDecodeError as e:
            raise CameraFileError(f"{p}: invalid JSON at line {e.lineno} column {e.colno}: "
                                  f"{e.msg}") from None
        if isinstance(data, dict) and _is_ros(data):
            return _from_ros(p, data)
        return _load_opencv(p)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise CameraFileError(f"{p}: not valid YAML ({str(e).splitlines()[0]}); expected an "
                              "OpenCV or ROS camera file") from None
    if isinstance(data, dict) and _is_ros(data):
        return _from_ros(p, data)
    raise CameraFileError(f"{p}: not a camera file: expected OpenCV FileStorage fields "
                          "'camera_matrix' and 'distortion_coefficients' or a ROS camera_info "
                          "YAML")


def _is_ros(data: dict) -> bool:
    cm = data.get("camera_matrix")
    return isinstance(cm, dict) and "data" in cm


def _check_K(p: Path, K: np.ndarray, field_name: str) -> np.ndarray:
    if K.shape != (3, 3):
        raise CameraFileError(f"{p}: {field_name}: expected a 3×3 matrix, got shape "
                              f"{tuple(K.shape)}")
    if not np.all(np.isfinite(K)):
        raise CameraFileError(f"{p}: {field_name}: contains NaN or infinity")
    if K[0, 0] <= 0 or K[1, 1] <= 0 or abs(K[2, 2] - 1) > 1e-9 or K[1, 0] or K[2, 0] or K[2, 1]:
        raise CameraFileError(f"{p}: {field_name}: not a camera matrix [[fx,0,cx],[0,fy,cy],"
                              "[0,0,1]] with positive focal lengths")
    return K


def _check_dist(p: Path, d: np.ndarray, field_name: str) -> np.ndarray:
    d = d.ravel()
    if d.size not in _VALID_DIST_LENGTHS:
        raise CameraFileError(f"{p}: {field_name}: {d.size} coefficients; OpenCV's Brown model "
                              "has 4, 5, 8, 12 or 14 (k1 k2 p1 p2 k3 ...)")
    if not np.all(np.isfinite(d)):
        raise CameraFileError(f"{p}: {field_name}: contains NaN or infinity")
    return d


def _size_or_guess(p: Path, w, h, K: np.ndarray) -> tuple[int, int]:
    if w and h:
        if int(w) <= 0 or int(h) <= 0:
            raise CameraFileError(f"{p}: image_width/image_height must be positive")
        return int(w), int(h)
    return int(round(2 * K[0, 2] + 1)), int(round(2 * K[1, 2] + 1))


def _node_mat(p: Path, node, field_name: str) -> np.ndarray | None:
    try:
        return node.mat()
    except cv2.error:
        raise CameraFileError(f"{p}: {field_name}: not a valid opencv-matrix (rows × cols must "
                              "match the number of values in data)") from None


def _load_opencv(p: Path) -> Camera:
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except cv2.error as e:
        raise CameraFileError(f"{p}: OpenCV cannot parse it ({str(e).strip().splitlines()[-1]})"
                              ) from None
    try:
        if not fs.isOpened():
            raise CameraFileError(f"{p}: OpenCV cannot open it as FileStorage YAML/XML/JSON")
        node = fs.getNode("camera_matrix")
        if node.empty():
            raise CameraFileError(f"{p}: camera_matrix: missing (an OpenCV camera file needs "
                                  "'camera_matrix' and 'distortion_coefficients')")
        K = _node_mat(p, node, "camera_matrix")
        if K is None:
            raise CameraFileError(f"{p}: camera_matrix: not an opencv-matrix")
        K = _check_K(p, np.asarray(K, dtype=np.float64), "camera_matrix")
        dnode = fs.getNode("distortion_coefficients")
        if dnode.empty():
            raise CameraFileError(f"{p}: distortion_coefficients: missing (write zeros for a "
                                  "lens without distortion)")
        d = _node_mat(p, dnode, "distortion_coefficients")
        if d is None:
            raise CameraFileError(f"{p}: distortion_coefficients: not an opencv-matrix")
        d = _check_dist(p, np.asarray(d, dtype=np.float64), "distortion_coefficients")
        w = fs.getNode("image_width")
        h = fs.getNode("image_height")
        width = int(w.real()) if not w.empty() else None
        height = int(h.real()) if not h.empty() else None
        name_node = fs.getNode("camera_name")
        name = name_node.string() if not name_node.empty() and name_node.isString() else "camera"
    finally:
        fs.release()
    width, height = _size_or_guess(p, width, height, K)
    return Camera(K=K, dist=d, width=width, height=height, name=name or "camera")


def _ros_matrix(p: Path, data: dict, key: str, rows: int | None, cols: int | None) -> np.ndarray:
    node = data.get(key)
    if not isinstance(node, dict) or "data" not in node:
        raise CameraFileError(f"{p}: {key}: missing or not a {{rows, cols, data}} mapping")
    try:
        arr = np.asarray(node["data"], dtype=np.float64)
    except (TypeError, ValueError):
        raise CameraFileError(f"{p}: {key}.data: must be a list of numbers") from None
    r = node.get("rows", rows)
    c = node.get("cols", cols)
    if r is not None and c is not None:
        if arr.size != int(r) * int(c):
            raise CameraFileError(f"{p}: {key}: rows×cols = {r}×{c} but data has {arr.size} "
                                  "values")
        arr = arr.reshape(int(r), int(c))
    return arr


def _from_ros(p: Path, data: dict) -> Camera:
    K = _check_K(p, _ros_matrix(p, data, "camera_matrix", 3, 3).reshape(3, 3), "camera_matrix")
    model = data.get("distortion_model", "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial"):
        raise CameraFileError(f"{p}: distortion_model: '{model}' is not supported; use "
                              "plumb_bob or rational_polynomial (OpenCV's Brown model)")
    d = _check_dist(p, _ros_matrix(p, data, "distortion_coefficients", None, None),
                    "distortion_coefficients")
    width, height = _size_or_guess(p, data.get("image_width"), data.get("image_height"), K)
    return Camera(K=K, dist=d, width=width, height=height,
                  name=str(data.get("camera_name", "camera")))


# ================================================================================ writing
def _atomic_write(path: Path, write_to_tmp) -> None:
    """Write through a temporary file in the same folder (named with ``path``'s suffix:
    OpenCV's FileStorage picks the format by it), then rename over ``path``."""
    from drovisio.fileio import atomic_write

    atomic_write(path, write_to_tmp, suffix=path.suffix, make_parents=True)


def _fmt_float(x: float) -> str:
    return repr(float(x))  # shortest string that round-trips a double exactly


def save_camera(camera: Camera, path: str | os.PathLike, fmt: CameraFormat | None = None) -> Path:
    """Write a camera file atomically, at full precision.

    Args:
        camera: The camera.
        path: Destination. Its suffix picks the form when ``fmt`` is None: ``.json`` → OpenCV
            JSON, ``.xml`` → OpenCV XML, anything else → OpenCV YAML.
        fmt: ``"opencv"`` (FileStorage YAML/XML by suffix), ``"ros"`` (camera_info YAML) or
            ``"json"`` (OpenCV FileStorage JSON).

    Returns:
        The path written.
    """
    p = Path(path)
    if fmt is None:
        fmt = "json" if p.suffix.lower() == ".json" else "opencv"
    if fmt == "ros":
        _atomic_write(p, lambda tmp: tmp.write_text(_ros_text(camera), encoding="utf-8"))
    elif fmt in ("opencv", "json"):
        suffix = ".json" if fmt == "json" else (".xml" if p.suffix.lower() == ".xml" else ".yaml")

        def write(tmp: Path) -> None:
            # FileStorage picks its syntax from the suffix, so write beside it under that suffix
            real = tmp.with_suffix(suffix)
            fs = cv2.FileStorage(str(real), cv2.FILE_STORAGE_WRITE)
            fs.write("image_width", camera.width)
            fs.write("image_height", camera.height)
            fs.write("camera_name", camera.name)
            fs.write("camera_matrix", camera.K)
            fs.write("distortion_coefficients", camera.dist.reshape(1, -1))
            fs.release()
            if real != tmp:
                os.replace(real, tmp)

        _atomic_write(p, write)
    else:
        raise ValueError(f"unknown camera file format {fmt!r}; use opencv, ros or json")
    return p


def _ros_text(camera: Camera) -> str:
    K = camera.K
    P = np.zeros((3, 4))
    P[:3, :3] = K
    model = "plumb_bob" if camera.dist.size <= 5 else "rational_polynomial"

    def block(name: str, rows: int, cols: int, values: np.ndarray) -> str:
        vals = ", ".join(_fmt_float(v) for v in np.ravel(values))
        return f"{name}:\n  rows: {rows}\n  cols: {cols}\n  data: [{vals}]\n"

    return (f"image_width: {camera.width}\nimage_height: {camera.height}\n"
            f"camera_name: {json.dumps(camera.name)}\n"
            + block("camera_matrix", 3, 3, K)
            + f"distortion_model: {model}\n"
            + block("distortion_coefficients", 1, camera.dist.size, camera.dist)
            + block("rectification_matrix", 3, 3, np.eye(3))
            + block("projection_matrix", 3, 4, P))
