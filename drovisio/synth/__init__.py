"""Synthetic scenes with exact ground truth: the test bed of every detector and of calibration.

The renderer is a ray caster, not a rasteriser: every sub-pixel sample's viewing ray is found by
undistorting its pixel position through the camera's lens model (OpenCV's Brown and rational
models, or the Kannala–Brandt fisheye: samples more than 90° off a fisheye's axis see the
background), and is intersected with the scene's planar polygons (ground, mesh triangles,
printed codes, dots, chessboards). Geometry is therefore exact under distortion: a 3D point
seen in the image is where ``Camera.project`` puts it. Anti-aliasing is a box filter over
``ss × ss`` samples per pixel, placed symmetrically about the pixel centre (pixel (0, 0) is
the centre of the top-left pixel). Image effects (blur, motion blur, lighting, noise, JPEG) are applied afterwards.

Frames: world z up, ground at z = 0, metres; camera frame is OpenCV's (x right, y down,
z forward); transforms are 4×4 ``a_from_b`` matrices (``p_a = a_from_b @ p_b``).

The package, by subject: :mod:`.scene` (the scene's description, camera poses, the truth),
:mod:`.textures` (paper, ink, paint, the procedural grounds), :mod:`.canvas` (the ray caster's
buffers and polygon drawing), :mod:`.markers` (meshes, codes, dots and boards drawn, each
brick's truth), :mod:`.effects` (image degradations) and :mod:`.renderer` (:func:`render`,
:func:`render_chessboard`, :func:`render_charuco`).
"""

from __future__ import annotations

from drovisio.geometry import rot_z, rvec_tvec, transform  # re-exported: callers import them here
from drovisio.synth.canvas import RENDER_BYTES_PER_SAMPLE, check_render_memory, check_render_work
from drovisio.synth.effects import apply_effects
from drovisio.synth.markers import brick_mesh_for
from drovisio.synth.renderer import render, render_charuco, render_chessboard
from drovisio.synth.scene import (
    Board,
    BrickInstance,
    BrickTruth,
    Effects,
    Ground,
    Prop,
    RenderResult,
    Scene,
    camera_over,
    look_at,
)
from drovisio.synth.textures import ground_texture

__all__ = [
    "Board", "BrickInstance", "Effects", "Ground", "Prop", "RenderResult", "Scene",
    "BrickTruth", "look_at", "camera_over", "render", "render_chessboard", "render_charuco",
    "ground_texture", "brick_mesh_for", "apply_effects", "check_render_memory",
    "check_render_work", "RENDER_BYTES_PER_SAMPLE", "rot_z", "rvec_tvec", "transform",
]
