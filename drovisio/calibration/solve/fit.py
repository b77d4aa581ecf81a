"""One solve of a model on a fixed set of views: each start in turn until one passes the
checks, then with fewer free coefficients, else refused in one line."""

from __future__ import annotations

import numpy as np

from drovisio.calibration.lm import Refined, make_camera
from drovisio.calibration.solve.checks import corner_noise_px, diagnose
from drovisio.calibration.solve.models import MODELS, RETRY_FIXED, fail_line
from drovisio.calibration.solve.results import CalibrationError, Model, ViewFit, ViewInput
from drovisio.calibration.solve.starts import candidates, pinhole_stages
from drovisio.calibration.uncertainty import (
    camera_model,
    covariance_from_information,
    param_names,
    schur_information,
    view_jacobian,
)
from drovisio.camera import Camera


def _model_from(ref: Refined, views: list[ViewInput], O, I, size, key: str,
                free: np.ndarray) -> Model:
    """The :class:`Model` (fits, covariance) of a refined solve."""
    cam = make_camera(ref.theta, key, size)
    cam = Camera(K=cam.K, dist=cam.dist, width=size[0], height=size[1], name="camera",
                 model=camera_model(key))
    jac, fits, ssr, n_obs = [], [], 0.0, 0
    for v, o, i, p in zip(views, O, I, ref.poses):
        A, B, px = view_jacobian(o, p[:3], p[3:], cam)
        jac.append((A, B))
        e2 = np.sum((px - i) ** 2, axis=1)
        ssr += float(e2.sum())
        n_obs += 2 * len(e2)
        fits.append(ViewFit(v.name, float(np.sqrt(e2.mean())), float(np.sqrt(e2.max())),
                            len(e2), p[:3].copy(), p[3:].copy()))
    dof = n_obs - int(free.sum()) - 6 * len(views)
    if dof <= 0:
        raise CalibrationError(f"{len(views)} views give too few corners for {free.sum()} + "
                               "6·views parameters; add views")
    sigma2 = ssr / dof
    S = schur_information(jac, free)
    cov = covariance_from_information(S, sigma2, free)
    # RMS over all corners (OpenCV's calibrateCamera definition, for every model)
    rms = float(np.sqrt(ssr / (n_obs / 2)))
    return Model(cam, rms, fits, free, S, sigma2, cov, rms_history=list(ref.rms_history))


def _checked(ref: Refined, start: str, views: list[ViewInput], O: list[np.ndarray],
             I: list[np.ndarray], size: tuple[int, int], model: str, free: np.ndarray,
             noise: float | None) -> tuple[Model | None, tuple[str, str] | None]:
    """The :class:`Model` of one start's solve when it passes :func:`diagnose`, else None
    and why not ((cause, fix))."""
    if not np.isfinite(ref.rms_px):
        return None, (f"diverged from the {start} (no finite reprojection)", "add varied views")
    m = _model_from(ref, views, O, I, size, model, free)
    why = diagnose(m, O, noise)
    return (m, None) if why is None else (None, why)


def _fit(views: list[ViewInput], size: tuple[int, int], fix_k3: bool,
         model: str = "plumb_bob", noise: float | None = None,
         fixed_coefficients: int = 0) -> Model:
    """Solve ``model`` and check it (:func:`diagnose`); a solve that fails the check is
    retried with its highest-order coefficients held at 0, and refused when that fails too.

    Raises:
        CalibrationError: one line: the model, the cause, the fix.
    """
    O = [np.asarray(v.object_points, np.float64).reshape(-1, 3) for v in views]
    I = [np.asarray(v.corners, np.float64).reshape(-1, 2) for v in views]
    if noise is None:
        noise = corner_noise_px(views)
    n = len(param_names(model))
    tries = [fixed_coefficients] if fixed_coefficients else [0, RETRY_FIXED[model]]
    if model == "plumb_bob" and fix_k3:
        tries = [1]
    first: tuple[str, str] | None = None
    stages: dict[bool, tuple[Refined, Refined]] = {}
    for k in tries:
        k3_fixed = fix_k3 or (model == "plumb_bob" and k > 0)
        if k3_fixed not in stages:
            stages[k3_fixed] = pinhole_stages(O, I, size, k3_fixed)
        free = np.ones(n, bool)
        if k:
            free[n - k:] = False
        for ref, start in candidates(O, I, size, model, stages[k3_fixed], k):
            m, why = _checked(ref, start, views, O, I, size, model, free, noise)
            if m is not None:
                m.start = start
                if k and first is not None and not (model == "plumb_bob" and fix_k3):
                    names = ", ".join(param_names(model)[n - k:])
                    m.retry_note = (f"{names} held at 0: with them free the solve "
                                    f"{first[0]}")
                return m
            first = first or why
        if first is None:
            first = ("found no start: no start's lens model sees the corners",
                     "check --board and --square, or try --model plumb_bob")
    assert first is not None
    raise CalibrationError(fail_line(model, *first))


def fit_model(views: list[ViewInput], image_size: tuple[int, int], fix_k3: bool = False,
              model: str = "plumb_bob", fixed_coefficients: int = 0) -> Model:
    """One solve (no outlier rejection, no model selection); ``fixed_coefficients`` holds
    that many of the model's highest-order coefficients at 0."""
    if len(views) < 3:
        raise CalibrationError(f"{len(views)} usable view(s); a calibration needs at least 3 "
                               "(10 or more, varied, for a good one)")
    return _fit(views, (int(image_size[0]), int(image_size[1])), fix_k3,
                MODELS.get(model, model), fixed_coefficients=fixed_coefficients)
