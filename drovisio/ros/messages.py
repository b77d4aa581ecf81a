"""The ROS 2 messages of one processed frame (dicts in the fields of :mod:`.msgdefs`).

:class:`RosMessages` turns a frame (its JPEG) and its :class:`~drovisio.pipeline.FrameOutput`
into ``(topic, type, message)`` triples, stamped with the frame's capture time; the MCAP
recorder and any other ROS output write these and nothing else. Topics are those of
:mod:`drovisio.ros` under ``namespace`` (default ``/drovisio``).

* ``bricks`` (``vision_msgs/Detection3DArray``, camera optical frame): every tracked brick of
  the frame, as the JSON output lists them; ``id`` is ``layout/instance`` (``layout/tN``,
  N the track, for bricks without ids); one hypothesis, ``class_id`` the layout, score 1
  when measured in this frame, 0.5 when held over; its pose is ``camera_from_brick`` with
  its covariance (:func:`drovisio.ros.frames.ros_covariance`); the box is the layout's
  ``dimensions`` about the brick frame's origin.
* ``target`` (``geometry_msgs/PoseWithCovarianceStamped``): the target brick, in the FLU
  body frame (``base_link``) when a mount is known, else in the camera optical frame.
* ``output`` (``std_msgs/String``): the frame's JSON output, unchanged (the contract of
  DESIGN.md), so a recording carries everything ``jsonl:`` gives.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence

import numpy as np

from drovisio.ros.frames import (
    BODY_FRAME,
    CAMERA_FRAME,
    flu_from_camera,
    pose_fields,
    pose_of,
    ros_covariance,
)

__all__ = ["TOPIC_TYPES", "RosMessages", "namespace_for", "stamp"]

#: Topic (relative to the namespace) → message type.
TOPIC_TYPES: dict[str, str] = {
    "camera/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
    "camera/camera_info": "sensor_msgs/msg/CameraInfo",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "bricks": "vision_msgs/msg/Detection3DArray",
    "target": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "output": "std_msgs/msg/String",
}

_DISTORTION_MODEL = {"plumb_bob": "plumb_bob", "rational_polynomial": "rational_polynomial",
                     "fisheye": "equidistant"}


def namespace_for(drone_id: str | None) -> tuple[str, str]:
    """(topic namespace, frame id prefix) of a drone: ``/drovisio`` and no prefix without an
    id, ``/drovisio/ID`` and ``ID/`` with one."""
    if not drone_id:
        return "/drovisio", ""
    return f"/drovisio/{drone_id}", f"{drone_id}/"


def stamp(t: float) -> dict:
    """``builtin_interfaces/Time`` of a UNIX time in seconds."""
    ns = int(round(t * 1e9))
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def _header(t: float, frame_id: str) -> dict:
    return {"stamp": stamp(t), "frame_id": frame_id}


def _cov_list(C: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(C, np.float64).ravel()]


class RosMessages:
    """Builds the messages of a run.

    Args:
        camera: The :class:`drovisio.camera.Camera` (for ``CameraInfo``).
        mount: The :class:`drovisio.mount.Mount`, or None (no ``/tf_static``; the target is
            then given in the camera frame).
        layouts: The loaded layouts (their ``dimensions`` size the boxes).
        namespace: Prefix of the topics (``/drovisio``; a drone id gives one per drone).
        frame_prefix: Prefix of the frame ids (e.g. ``drone1/``), empty by default.
    """

    def __init__(self, camera=None, mount=None, layouts: Sequence = (),
                 namespace: str = "/drovisio", frame_prefix: str = ""):
        self.camera = camera
        self.mount = mount
        self.sizes: Mapping[str, np.ndarray] = {}
        sizes = {}
        for lay in layouts:
            sizes[lay.name] = np.asarray(lay.dimensions_m, np.float64)
        self.sizes = sizes
        self.namespace = "/" + namespace.strip("/") if namespace.strip("/") else ""
        self.body_frame = frame_prefix + BODY_FRAME
        self.camera_frame = frame_prefix + CAMERA_FRAME

    def topic(self, name: str) -> str:
        """The full topic name of a :data:`TOPIC_TYPES` key."""
        return name if name.startswith("/") else f"{self.namespace}/{name}"

    # ------------------------------------------------------------------ per run
    def camera_info(self, t: float) -> dict:
        cam = self.camera
        K = np.asarray(cam.K, np.float64)
        P = np.zeros((3, 4))
        P[:, :3] = K
        return {"header": _header(t, self.camera_frame), "height": int(cam.height),
                "width": int(cam.width),
                "distortion_model": _DISTORTION_MODEL.get(cam.model, cam.model),
                "d": [float(v) for v in np.ravel(cam.dist)],
                "k": [float(v) for v in K.ravel()],
                "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                "p": [float(v) for v in P.ravel()], "binning_x": 0, "binning_y": 0,
                "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0,
                        "do_rectify": False}}

    def tf_static(self, t: float) -> dict:
        """``base_link`` (FLU) → ``camera_optical_frame``: the mount, converted from FRD."""
        T = flu_from_camera(self.mount.body_from_camera)
        q = pose_fields(T)
        return {"transforms": [{
            "header": _header(t, self.body_frame), "child_frame_id": self.camera_frame,
            "transform": {"translation": q["position"], "rotation": q["orientation"]}}]}

    # ------------------------------------------------------------------ per frame
    @staticmethod
    def compressed_image(data: bytes, t: float, frame_id: str, fmt: str = "jpeg") -> dict:
        return {"header": _header(t, frame_id), "format": fmt, "data": data}

    def detections(self, output) -> dict:
        dets = []
        for b in output.bricks:
            ident = f"{b.layout}/{b.instance}" if b.instance is not None \
                else f"{b.layout}/t{b.track}"
            T = pose_of(b.rvec, b.tvec)
            cov = ros_covariance(b.rvec, b.covariance) if b.covariance is not None \
                else np.zeros((6, 6))
            size = self.sizes.get(b.layout, np.zeros(3))
            pose = pose_fields(T)
            dets.append({
                "header": _header(output.t, self.camera_frame),
                "results": [{"hypothesis": {"class_id": b.layout,
                                            "score": 1.0 if b.measured else 0.5},
                             "pose": {"pose": pose, "covariance": _cov_list(cov)}}],
                "bbox": {"center": pose, "size": {"x": float(size[0]), "y": float(size[1]),
                                                  "z": float(size[2])}},
                "id": ident})
        return {"header": _header(output.t, self.camera_frame), "detections": dets}

    def target(self, output) -> dict | None:
        b = output.target
        if b is None:
            return None
        T = pose_of(b.rvec, b.tvec)
        frame = self.camera_frame
        parent = None
        if self.mount is not None:
            parent = flu_from_camera(self.mount.body_from_camera)
            T = parent @ T
            frame = self.body_frame
        cov = ros_covariance(b.rvec, b.covariance, parent) if b.covariance is not None \
            else np.zeros((6, 6))
        return {"header": _header(output.t, frame),
                "pose": {"pose": pose_fields(T), "covariance": _cov_list(cov)}}

    @staticmethod
    def output_string(output) -> dict:
        return {"data": json.dumps(output.to_json(), separators=(",", ":"))}

    def frame_messages(self, output, jpeg: bytes | None, image_format: str = "jpeg"
                       ) -> list[tuple[str, str, dict]]:
        """``(topic, type, message)`` of one frame, image first (``jpeg``: the encoded
        image, in ``image_format``, jpeg or png)."""
        out: list[tuple[str, str, dict]] = []
        if jpeg is not None and self.camera is not None:   # with each image, as ROS does
            out.append((self.topic("camera/camera_info"), TOPIC_TYPES["camera/camera_info"],
                        self.camera_info(output.t)))
        if jpeg is not None:
            out.append((self.topic("camera/image_raw/compressed"),
                        TOPIC_TYPES["camera/image_raw/compressed"],
                        self.compressed_image(jpeg, output.t, self.camera_frame,
                                              image_format)))
        out.append((self.topic("bricks"), TOPIC_TYPES["bricks"], self.detections(output)))
        tgt = self.target(output)
        if tgt is not None:
            out.append((self.topic("target"), TOPIC_TYPES["target"], tgt))
        out.append((self.topic("output"), TOPIC_TYPES["output"], self.output_string(output)))
        return out

    def run_messages(self, t: float) -> list[tuple[str, str, dict]]:
        """The messages said once per run (the mount)."""
        out: list[tuple[str, str, dict]] = []
        if self.mount is not None:
            out.append(("/tf_static", TOPIC_TYPES["/tf_static"], self.tf_static(t)))
        return out

