"""ROS 2 messages: definitions as ROS 2 Humble has them, the FRD → FLU conversion, and the
covariance converted to ROS's order and axes (checked by sampling)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drovisio.camera import Camera
from drovisio.fusion import so3_exp, so3_log
from drovisio.mount import Mount, body_from_camera_angles
from drovisio.pose.covariance import pose_error, uncertainty_words
from drovisio.ros.frames import FLU_FROM_FRD, flu_from_camera, pose_fields, ros_covariance
from drovisio.ros.messages import RosMessages
from drovisio.ros.msgdefs import DEFINITIONS, encoder, schema_text


def _store():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


@pytest.mark.parametrize("name", sorted(n for n in DEFINITIONS
                                        if not n.startswith(("vision_msgs", "builtin"))))
def test_standard_definitions_are_ros2_humbles(name):
    """Our text, parsed by rosbags, gives the fields of rosbags' own ROS 2 Humble store."""
    from rosbags.typesys import get_types_from_msg

    pkg, typ = name.split("/")
    full = f"{pkg}/msg/{typ}"
    ours = get_types_from_msg(DEFINITIONS[name], full)[full]
    want = _store().fielddefs[full]
    assert [f[0] for f in ours[1]] == [f[0] for f in want[1]]
    assert [f[1] for f in ours[1]] == [f[1] for f in want[1]]


def test_vision_msgs_decode_with_another_library():
    """A Detection3DArray we encode, decoded by rosbags from our definitions' text."""
    from rosbags.typesys import get_types_from_msg

    store = _store()
    types = {}
    for n in ("vision_msgs/ObjectHypothesis", "vision_msgs/ObjectHypothesisWithPose",
              "vision_msgs/BoundingBox3D", "vision_msgs/Detection3D",
              "vision_msgs/Detection3DArray"):
        pkg, typ = n.split("/")
        types.update(get_types_from_msg(DEFINITIONS[n], f"{pkg}/msg/{typ}"))
    store.register(types)
    T = np.eye(4)
    T[:3, :3] = so3_exp(np.array([0.1, -0.2, 0.3]))
    T[:3, 3] = [0.1, 0.2, 1.5]
    pose = pose_fields(T)
    cov = np.arange(36, dtype=float) * 1e-6
    msg = {"header": {"stamp": {"sec": 5, "nanosec": 7}, "frame_id": "camera_optical_frame"},
           "detections": [{"header": {"stamp": {"sec": 5, "nanosec": 7}, "frame_id": "c"},
                           "results": [{"hypothesis": {"class_id": "drick", "score": 1.0},
                                        "pose": {"pose": pose, "covariance": list(cov)}}],
                           "bbox": {"center": pose, "size": {"x": 0.3, "y": 0.15, "z": 0.12}},
                           "id": "drick/4"}]}
    raw = encoder("vision_msgs/Detection3DArray")(msg)
    m = store.deserialize_cdr(raw, "vision_msgs/msg/Detection3DArray")
    d = m.detections[0]
    assert d.id == "drick/4" and d.results[0].hypothesis.class_id == "drick"
    np.testing.assert_array_equal(d.results[0].pose.covariance, cov)
    assert d.bbox.size.y == 0.15 and d.results[0].pose.pose.position.z == 1.5
    assert "MSG: geometry_msgs/PoseWithCovariance" in schema_text("vision_msgs/Detection3DArray")


def test_frd_to_flu():
    fwd, right, down = np.eye(3)
    F = FLU_FROM_FRD[:3, :3]
    np.testing.assert_array_equal(F @ fwd, [1, 0, 0])      # forward stays forward
    np.testing.assert_array_equal(F @ right, [0, -1, 0])   # right is −left
    np.testing.assert_array_equal(F @ down, [0, 0, -1])    # down is −up
    # a camera looking straight down from the body: its optical axis is FLU −z
    T = flu_from_camera(body_from_camera_angles(tilt_deg=0.0))
    np.testing.assert_allclose(T[:3, :3] @ [0, 0, 1], [0, 0, -1], atol=1e-12)


def test_covariance_conversion_by_sampling():
    """Poses drawn from a covariance of (rvec, tvec), each turned into ROS's FLU body frame,
    scatter as the converted 6×6 says (order x y z, rotation about X Y Z)."""
    rng = np.random.default_rng(3)
    rvec = np.array([2.4, -0.7, 0.3])
    tvec = np.array([0.2, -0.1, 1.8])
    A = rng.normal(size=(6, 6))
    S = A @ A.T + np.eye(6)
    S = S * np.r_[[math.radians(1.5)] * 3, [0.01] * 3][:, None] \
        * np.r_[[math.radians(1.5)] * 3, [0.01] * 3][None, :] / 6
    parent = flu_from_camera(body_from_camera_angles(tilt_deg=35.0, pan_deg=-20.0,
                                                     roll_deg=5.0, offset_m=(0.1, 0.02, 0.03)))
    want = ros_covariance(rvec, S, parent)
    T0 = np.eye(4)
    T0[:3, :3], T0[:3, 3] = so3_exp(rvec), tvec
    M0 = parent @ T0
    x = rng.multivariate_normal(np.r_[rvec, tvec], S, size=40000)
    errs = np.empty((len(x), 6))
    for i, p in enumerate(x):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = so3_exp(p[:3]), p[3:]
        M = parent @ T
        errs[i] = pose_error(M[:3, :3], M[:3, 3], M0[:3, :3], M0[:3, 3])
    got = np.cov(errs.T)
    sd = np.sqrt(np.diag(want))
    # correlation-scaled agreement: within sampling error (1/sqrt(40000) = 0.005) + the
    # linearisation (rotations of ~1.5°)
    np.testing.assert_allclose(got / np.outer(sd, sd), want / np.outer(sd, sd), atol=0.03)
    # the order matters: position first (metres), rotation after (radians)
    assert np.all(np.diag(want)[:3] < 1e-3) and np.all(np.diag(want)[3:] > 1e-5)


def test_camera_info_names_the_lens_model_as_ros_does():
    fish = Camera(K=np.array([[300.0, 0, 320], [0, 300, 240], [0, 0, 1]]),
                  dist=np.array([0.1, -0.02, 0.003, -0.001]), model="fisheye")
    info = RosMessages(fish).camera_info(12.5)
    assert info["distortion_model"] == "equidistant" and len(info["d"]) == 4
    assert info["p"][:3] == [300.0, 0.0, 320.0] and info["p"][3] == 0.0
    assert info["header"]["stamp"] == {"sec": 12, "nanosec": 500000000}
    assert RosMessages(Camera.drone_webcam()).camera_info(0)["distortion_model"] == "plumb_bob"


def test_tf_static_is_the_mount_in_flu():
    bfc = body_from_camera_angles(tilt_deg=30.0, offset_m=(0.12, 0.0, 0.05))
    tf = RosMessages(Camera.drone_webcam(), Mount(bfc)).tf_static(0.0)["transforms"][0]
    tr = tf["transform"]["translation"]
    assert (tr["x"], tr["y"], tr["z"]) == pytest.approx((0.12, 0.0, -0.05))  # 5 cm below: z −
    q = tf["transform"]["rotation"]
    R = so3_exp(so3_log(flu_from_camera(bfc)[:3, :3]))
    w = math.sqrt(max(0.0, 1 + np.trace(R))) / 2
    assert q["w"] == pytest.approx(w, abs=1e-9)


def test_uncertainty_in_words():
    C = np.diag([0.004 ** 2, 0.001 ** 2, 0.002 ** 2] + [math.radians(0.3) ** 2] * 3)
    assert uncertainty_words(C) == "± 4.0 mm, ± 0.30°"
    C = np.diag([0.03 ** 2] * 3 + [math.radians(2.5) ** 2] * 3)
    assert uncertainty_words(C) == "± 30 mm, ± 2.5°"
    assert uncertainty_words(None) == ""


def test_the_brick_boxes_are_sized_by_their_layouts():
    """Each layout's box is its ``dimensions`` in metres (it was 0 × 0 × 0 for every one)."""
    from drovisio.layout import load_layout
    from drovisio.resources import layouts_dir

    lay = load_layout(layouts_dir() / "drick-aruco-centre.json")
    msgs = RosMessages(layouts=[lay])
    np.testing.assert_allclose(msgs.sizes[lay.name], lay.dimensions_m)
    assert (msgs.sizes[lay.name] > 0.05).all()
