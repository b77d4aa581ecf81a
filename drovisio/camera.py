"""A calibrated camera: intrinsics, lens model and image size, and projection through them.

Conventions (DESIGN.md):
    * Camera frame: OpenCV's (x right, y down, z forward), metres.
    * Pixel (0, 0) is the centre of the top-left pixel.
    * Lens models, named as ROS names them:

      - ``plumb_bob``: OpenCV's Brown model, coefficients (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3
        s4 [tx ty]]]]): 4, 5, 8, 12 or 14 of them, as ``cv2.calibrateCamera`` writes them;
      - ``rational_polynomial``: the same with 8 or more coefficients (k4–k6 in use);
      - ``fisheye``: OpenCV's Kannala–Brandt model (``cv2.fisheye``), 4 coefficients
        (k1 k2 k3 k4); ROS and Kalibr call it ``equidistant``.

Every projection (:meth:`Camera.project`) and undistortion (:meth:`Camera.normalize`) honours
the model; code that needs OpenCV's functions directly asks :meth:`Camera.cv_project` and
:meth:`Camera.cv_undistort` rather than passing ``dist`` itself.

Reading and writing camera files: :mod:`drovisio.camera_file`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from types import ModuleType
from typing import Literal

import cv2
import numpy as np

__all__ = ["BROWN_LENGTHS", "Camera", "LensModel", "MODEL_ALIASES", "check_coefficients", "skew_problem"]

LensModel = Literal["plumb_bob", "rational_polynomial", "fisheye"]
BROWN_LENGTHS = (4, 5, 8, 12, 14)
MODEL_ALIASES: dict[str, LensModel] = {
    "plumb_bob": "plumb_bob",
    "rational_polynomial": "rational_polynomial",
    "fisheye": "fisheye",
    "equidistant": "fisheye",   # ROS camera_calibration's and Kalibr's name for it
}
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
# central differences of one pixel: the point, then ±x, then ±y
PIXEL_STENCIL = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


def skew_problem(skew: float, fx: float) -> str | None:
    """Why a camera matrix's skew ``K[0][1]`` cannot be used (None when it is zero): OpenCV's
    projection and undistortion, which every path here goes through, take none, so a skewed
    matrix would be used as if it had none."""
    if abs(skew) <= 1e-9 * abs(fx):
        return None
    return (f"skew K[0][1] = {skew:.6g} is not supported (OpenCV's projection takes none): "
            "calibrate with zero skew, as OpenCV's and ROS's calibrators do")


def check_coefficients(model: str, n: int) -> str | None:
    """Why ``n`` coefficients do not fit ``model`` (None when they do)."""
    if model == "fisheye":
        return None if n == 4 else (f"{n} coefficients; the fisheye (Kannala-Brandt) model "
                                    "has 4 (k1 k2 k3 k4)")
    if n not in BROWN_LENGTHS:
        return (f"{n} coefficients; OpenCV's model has 4, 5, 8, 12 or 14 (k1 k2 p1 p2 k3 "
                "...)")
    if model == "rational_polynomial" and n < 8:
        return f"{n} coefficients; rational_polynomial needs 8 or more (k1 k2 p1 p2 k3 k4 k5 k6)"
    return None


@dataclass(frozen=True)
class Camera:
    """Intrinsics, lens model and image size of a calibrated camera.

    Args:
        K: 3×3 camera matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]] in pixels.
        dist: Distortion coefficients of ``model`` (see the module doc).
        width: Image width in pixels the intrinsics belong to.
        height: Image height in pixels.
        name: Free-form camera name (kept in ROS files).
        model: Lens model: ``plumb_bob``, ``rational_polynomial`` or ``fisheye``.
        size_known: False when the camera file gave no image size: ``width``/``height`` are
            then a guess from the principal point until :meth:`for_image` sets them from the
            first image or the source.
    """

    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width: int = 640
    height: int = 480
    name: str = "camera"
    model: LensModel = "plumb_bob"
    size_known: bool = True

    def __post_init__(self) -> None:
        K = np.array(self.K, dtype=np.float64).reshape(3, 3)
        dist = np.array(self.dist, dtype=np.float64).ravel()
        model = MODEL_ALIASES.get(self.model)
        if model is None:
            raise ValueError(f"unknown lens model {self.model!r}: use plumb_bob, "
                             "rational_polynomial or fisheye")
        if dist.size >= 8 and model == "plumb_bob":
            model = "rational_polynomial"
        why = check_coefficients(model, dist.size)
        if why:
            raise ValueError(f"distortion has {why}")
        why = skew_problem(K[0, 1], K[0, 0])
        if why:
            raise ValueError(why)
        K.flags.writeable = False
        dist.flags.writeable = False
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # ----------------------------------------------------------------------------- builders
    @classmethod
    def from_fov(cls, width: int = 640, height: int = 480, hfov_deg: float = 60.0,
                 dist: np.ndarray | list[float] | None = None, name: str = "camera",
                 model: LensModel = "plumb_bob") -> Camera:
        """A camera with square pixels, centred principal point and the given horizontal FOV.

        Args:
            width: Image width in pixels.
            height: Image height in pixels.
            hfov_deg: Horizontal field of view in degrees. Pinhole models: of the pinhole
                part; fisheye: of the equidistant part (``f = (width/2) / (hfov/2)``), so
                180° and more are possible.
            dist: Distortion coefficients; zeros if omitted.
            name: Camera name.
            model: Lens model.
        """
        half = math.radians(hfov_deg) / 2.0
        if model == "fisheye":
            f = (width / 2.0) / half
            default = np.zeros(4)
        else:
            f = (width / 2.0) / math.tan(half)
            default = np.zeros(5)
        K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0, 0, 1.0]])
        return cls(K=K, dist=default if dist is None else np.asarray(dist, float),
                   width=width, height=height, name=name, model=model)

    @classmethod
    def drone_webcam(cls) -> Camera:
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

    @property
    def is_fisheye(self) -> bool:
        return self.model == "fisheye"

    def hfov_deg(self) -> float:
        """Horizontal field of view of the lens's ideal part, degrees: the pinhole's for
        plumb_bob/rational models, the equidistant projection's for fisheye (the one
        :meth:`from_fov` takes)."""
        half = self.width / 2.0 / self.fx
        return math.degrees(2 * (half if self.is_fisheye else math.atan(half)))

    def scaled(self, width: int, height: int) -> Camera:
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
        return replace(self, K=K, dist=self.dist.copy(), width=width, height=height,
                       size_known=True)

    def for_image(self, width: int, height: int) -> tuple[Camera, str | None]:
        """This camera for images of ``width`` × ``height``.

        A camera whose file gave no size takes the image's, with a note when the principal
        point is far from that image's centre (the file may be for another resolution).

        Returns:
            (camera, note or None).

        Raises:
            ValueError: The file's size differs from the image's.
        """
        if self.size_known:
            if (width, height) != self.size:
                raise ValueError(f"image is {width}x{height} but the camera file is for "
                                 f"{self.width}x{self.height}")
            return self, None
        cam = replace(self, width=int(width), height=int(height), size_known=True)
        off_x = abs(self.cx - (width - 1) / 2) / width
        off_y = abs(self.cy - (height - 1) / 2) / height
        note = None
        if off_x > 0.1 or off_y > 0.1:
            note = (f"the camera file gives no image size; using {width}x{height} from the "
                    f"images, but its principal point ({self.cx:.0f}, {self.cy:.0f}) is far "
                    "from their centre: is the file for another resolution?")
        return cam, note

    def almost_equal(self, other: Camera, rtol: float = 1e-12) -> bool:
        """True when the two cameras agree to ``rtol`` relative (distortion padded with zeros)."""
        if (self.model == "fisheye") != (other.model == "fisheye"):
            return False
        n = max(self.dist.size, other.dist.size)
        d1 = np.pad(self.dist, (0, n - self.dist.size))
        d2 = np.pad(other.dist, (0, n - other.dist.size))
        return (self.size == other.size and self.size_known == other.size_known
                and np.allclose(self.K, other.K, rtol=rtol, atol=0)
                and np.allclose(d1, d2, rtol=rtol, atol=1e-300))

    # ----------------------------------------------------------------------------- geometry
    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Project camera-frame points (N, 3) in metres to distorted pixels (N, 2)."""
        pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 1, 3)
        if pts.shape[0] == 0:
            return np.zeros((0, 2))
        return self.cv_project(pts, np.zeros(3), np.zeros(3))

    def cv_project(self, object_points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray
                   ) -> np.ndarray:
        """``cv2.projectPoints`` (or ``cv2.fisheye.projectPoints``) of object points (N, 3)
        seen with pose (rvec, tvec), as pixels (N, 2)."""
        pts = np.asarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
        if pts.shape[0] == 0:
            return np.zeros((0, 2))
        rvec = np.ascontiguousarray(np.asarray(rvec, np.float64).reshape(3, 1))
        tvec = np.ascontiguousarray(np.asarray(tvec, np.float64).reshape(3, 1))
        if self.is_fisheye:
            px, _ = cv2.fisheye.projectPoints(pts, rvec, tvec, self.K, self.dist)
        else:
            px, _ = cv2.projectPoints(pts, rvec, tvec, self.K, self.dist)
        return px.reshape(-1, 2)

    def project_points(self, object_points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) of object points (N, 3) seen with pose (rvec, tvec)
        (``camera_from_object``), and their Jacobian (2N, 6) with respect to (rvec, tvec),
        through this camera's lens model (rows x0, y0, x1, y1, ...)."""
        pts = np.asarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
        if pts.shape[0] == 0:
            return np.zeros((0, 2)), np.zeros((0, 6))
        rvec = np.ascontiguousarray(np.asarray(rvec, np.float64).reshape(3, 1))
        tvec = np.ascontiguousarray(np.asarray(tvec, np.float64).reshape(3, 1))
        if self.is_fisheye:
            # columns: fx fy cx cy k1..k4 | rvec | tvec | alpha
            px, J = cv2.fisheye.projectPoints(pts, rvec, tvec, self.K, self.dist)
            return px.reshape(-1, 2), J[:, 8:14]
        px, J = cv2.projectPoints(pts, rvec, tvec, self.K, self.dist)
        return px.reshape(-1, 2), J[:, :6]

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
        polynomial folds back, or at 90° and more from the axis of a fisheye) come out as NaN.
        """
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        if px.shape[0] == 0:
            return np.zeros((0, 2))
        if self.is_fisheye:
            return self._normalize_fisheye(px.reshape(-1, 2))
        xy = cv2.undistortPoints(px, self.K, self.dist, None, np.eye(3), np.eye(3),
                                 _UNDISTORT_CRITERIA).reshape(-1, 2)
        if self.dist.size <= 12 and np.any(self.dist):
            xy = self._polish(xy, px.reshape(-1, 2))
        return xy

    # -------------------------------------------------------------- compiled lens model
    def _compiled_lens(self) -> tuple[ModuleType, np.ndarray] | None:
        """The compiled lens model's module and this lens's 12 coefficients, or None when it
        cannot serve (kernels off, fisheye, tilted sensor)."""
        if self.is_fisheye:
            return None
        # numba is heavy to import (~1 s): loaded only when a fast path is asked for
        from drovisio import _numba, camera_kernels
        d12 = camera_kernels.lens_coefficients(self.dist)
        if d12 is None or not _numba.enabled():
            return None
        return camera_kernels, d12

    def normalize_local(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised coordinates (N, 2) of pixels (N, 2) and the local Jacobian
        d(normalised)/d(pixel) (N, 2, 2).

        The compiled lens model (:mod:`drovisio.camera_kernels`, Newton's method with the
        analytic Jacobian) where it serves; else :meth:`normalize` and central differences
        of one pixel. The two agree to ~1e-12.
        """
        c = np.asarray(pixels, np.float64).reshape(-1, 2)
        lens = self._compiled_lens()
        if lens is not None:
            kernels, d12 = lens
            return kernels.undistort(np.ascontiguousarray(c), float(self.K[0, 0]),
                                     float(self.K[1, 1]), float(self.K[0, 2]),
                                     float(self.K[1, 2]), d12)
        n = c.shape[0]
        pts = (c[None] + PIXEL_STENCIL[:, None, :]).reshape(-1, 2)
        qn = self.normalize_fast(pts).reshape(5, n, 2)
        J = np.stack([qn[1] - qn[2], qn[3] - qn[4]], axis=2) * 0.5        # (N, 2, 2)
        return qn[0], J

    def normalize_fast(self, pixels: np.ndarray) -> np.ndarray:
        """:meth:`normalize` (pixels (N, 2) → normalised (N, 2)) with the compiled lens model
        where it serves (see :meth:`normalize_local`)."""
        px = np.asarray(pixels, np.float64).reshape(-1, 1, 2)
        if px.shape[0] == 0:
            return np.zeros((0, 2))
        lens = self._compiled_lens()
        if lens is not None:
            kernels, d12 = lens
            return kernels.undistort(np.ascontiguousarray(px, np.float64).reshape(-1, 2),
                                     float(self.K[0, 0]), float(self.K[1, 1]),
                                     float(self.K[0, 2]), float(self.K[1, 2]), d12)[0]
        return self.normalize(px.reshape(-1, 2))

    def project_fast(self, points_cam: np.ndarray) -> np.ndarray:
        """:meth:`project` of camera-frame points (..., 3) to pixels (..., 2), with the
        compiled lens model where it serves (see :meth:`normalize_local`)."""
        Y = np.asarray(points_cam)
        shp = Y.shape[:-1]
        flat = Y.reshape(-1, 3)
        if flat.shape[0] == 0:
            return np.zeros(shp + (2,))
        lens = self._compiled_lens()
        if lens is not None:
            kernels, d12 = lens
            return kernels.project(np.ascontiguousarray(flat, np.float64), float(self.K[0, 0]),
                                   float(self.K[1, 1]), float(self.K[0, 2]),
                                   float(self.K[1, 2]), d12).reshape(shp + (2,))
        return self.project(flat).reshape(shp + (2,))

    def cv_undistort(self, pixels: np.ndarray) -> np.ndarray:
        """Alias of :meth:`normalize` for code that mirrors ``cv2.undistortPoints``."""
        return self.normalize(pixels)

    def _distorted_normalized(self, px: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) → distorted normalised coordinates (K⁻¹; no skew, see
        :func:`skew_problem`)."""
        Kinv = np.linalg.inv(self.K)
        return px @ Kinv[:2, :2].T + Kinv[:2, 2]

    def _normalize_fisheye(self, px: np.ndarray) -> np.ndarray:
        """Kannala–Brandt: θ_d = θ(1 + k1θ² + k2θ⁴ + k3θ⁶ + k4θ⁸), solved for θ by Newton
        from OpenCV's estimate; the point's direction is kept. θ ≥ 90° has no (x/z, y/z)."""
        target = self._distorted_normalized(px)
        rd = np.hypot(target[:, 0], target[:, 1])
        est = cv2.fisheye.undistortPoints(px.reshape(-1, 1, 2), self.K, self.dist,
                                          R=np.eye(3), P=np.eye(3)).reshape(-1, 2)
        theta = np.arctan(np.hypot(est[:, 0], est[:, 1]))
        bad = ~np.isfinite(theta)
        theta = np.where(bad, rd, theta)   # θ_d is a fine start where OpenCV gave up
        k1, k2, k3, k4 = self.dist
        for _ in range(8):
            t2 = theta * theta
            f = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - rd
            df = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            theta = theta - f / np.where(np.abs(df) < 1e-12, 1e-12, df)
        t2 = theta * theta
        residual = np.abs(theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - rd)
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(rd > 1e-15, np.tan(theta) / np.where(rd > 1e-15, rd, 1.0), 1.0)
        xy = target * scale[:, None]
        unreachable = (theta >= math.pi / 2) | (theta < 0) | ~(residual < 1e-9)
        xy[unreachable] = np.nan
        return xy

    def _polish(self, xy: np.ndarray, px: np.ndarray, steps: int = 4) -> np.ndarray:
        """Newton steps on distort(x) = target where OpenCV's fixed-point iteration has not
        converged (it can stall near strongly distorted image corners)."""
        target = self._distorted_normalized(px)
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
