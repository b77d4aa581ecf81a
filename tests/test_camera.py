"""Camera model: file round trips at full precision, projection, undistortion, bad files."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio.camera import Camera
from drovisio.camera_file import CameraFileError, load_camera, save_camera

OPENCV_SAMPLE_YAML = """%YAML:1.0
---
calibration_time: "Sun Nov 22 10:00:00 2026"
image_width: 640
image_height: 480
flags: 0
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 5.3280072497128633e+02, 0., 3.4215652571342125e+02, 0.,
       5.3291936167637296e+02, 2.3355283829713541e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -2.8131186449938911e-01, 2.4865571549548312e-02,
       1.2112006620993484e-03, -1.3408640690051620e-04,
       1.5855049604633488e-01 ]
avg_reprojection_error: 1.9e-01
"""

ROS_SAMPLE_YAML = """image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [532.80072497128633, 0, 342.15652571342125, 0, 532.91936167637296, 233.55283829713541, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.28131186449938911, 0.024865571549548312, 0.0012112006620993484, -0.0001340864069005162, 0.15855049604633488]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [532.8, 0, 342.1, 0, 0, 532.9, 233.5, 0, 0, 0, 1, 0]
"""


def awkward_camera(ncoef: int) -> Camera:
    """Values with many significant digits, so that any rounding shows."""
    K = np.array([[1600 / 3, 0.0, 320.123456789012345], [0, 533.987654321098765, 241.0 / 7],
                  [0, 0, 1]])
    d = np.array([-0.2813118644993891, 0.024865571549548312, 1.2112006620993484e-03,
                  -1.340864069005162e-04, 1 / 7, 1e-17, -3.3e-5, 2 / 3, 1e-3, -2e-3, 3e-4,
                  -4e-4, 1e-4, -2e-4])[:ncoef]
    return Camera(K=K, dist=d, width=640, height=480, name="awkward")


# ROS camera_info names plumb_bob (5) and rational_polynomial (8); its image_geometry hands
# D to OpenCV as it is, so the thin prism (12) and tilted (14) forms travel as
# rational_polynomial too
ROUND_TRIPS = [(n, suffix, fmt) for n in (4, 5, 8, 12, 14)
               for suffix, fmt in [(".yaml", None), (".xml", None), (".json", None),
                                   (".json", "json"), (".yaml", "ros")]
               if fmt != "ros" or n != 4]


@pytest.mark.parametrize("ncoef,suffix,fmt", ROUND_TRIPS)
def test_round_trip_full_precision(tmp_path: Path, ncoef: int, suffix: str, fmt):
    cam = awkward_camera(ncoef)
    path = save_camera(cam, tmp_path / f"cam{suffix}", fmt)
    back = load_camera(path)
    assert back.size == (640, 480)
    np.testing.assert_allclose(back.K, cam.K, rtol=1e-12, atol=0)
    assert back.dist.size == ncoef
    np.testing.assert_allclose(back.dist, cam.dist, rtol=1e-12, atol=0)
    assert list(tmp_path.iterdir()) == [path]  # atomic write leaves no temporary file


def test_reads_opencv_sample_and_ros_alike(tmp_path: Path):
    (tmp_path / "cv.yaml").write_text(OPENCV_SAMPLE_YAML)
    (tmp_path / "ros.yaml").write_text(ROS_SAMPLE_YAML)
    a = load_camera(tmp_path / "cv.yaml")
    b = load_camera(tmp_path / "ros.yaml")
    assert a.fx == pytest.approx(532.80072497128633, rel=1e-15)
    assert a.dist.size == 5 and a.dist[4] == pytest.approx(0.15855049604633488, rel=1e-15)
    assert b.name == "narrow_stereo"
    assert a.almost_equal(b, rtol=1e-14)


def test_size_guessed_from_principal_point_when_absent(tmp_path: Path):
    text = "\n".join(line for line in OPENCV_SAMPLE_YAML.splitlines()
                     if not line.startswith("image_"))
    (tmp_path / "c.yaml").write_text(text)
    cam = load_camera(tmp_path / "c.yaml")
    assert not cam.size_known
    assert cam.size == (685, 468)  # 2·cx + 1, a guess until an image gives the size
    sized, note = cam.for_image(640, 480)
    assert sized.size == (640, 480) and sized.size_known and note is None
    assert sized.fx == cam.fx and sized.cx == cam.cx


def test_project_matches_opencv_and_undistort_inverts_it():
    cam = Camera.drone_webcam()
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-0.5, 0.5, (200, 2)), rng.uniform(1, 3, 200)]
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K, cam.dist)
    px = cam.project(pts)
    np.testing.assert_allclose(px, ref.reshape(-1, 2), atol=1e-9)
    # undistortion inverts projection to 1e-9 px over the whole image, corners included
    grid = np.stack(np.meshgrid(np.linspace(0, 639, 33), np.linspace(0, 479, 25)), -1)
    grid = grid.reshape(-1, 2)
    xy = cam.normalize(grid)
    back = cam.project(np.c_[xy, np.ones(len(xy))])
    assert np.abs(back - grid).max() < 1e-9
    rays = cam.rays(grid)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0)
    und = cam.undistort_points(grid)
    np.testing.assert_allclose(und, xy @ cam.K[:2, :2].T + cam.K[:2, 2])


def test_a_skewed_pixel_grid_is_refused_in_one_line(tmp_path: Path):
    """OpenCV's projection (and so every path here) takes no skew: a camera matrix with one
    would be used as if it had none. The file is refused, naming the field and the fix."""
    f = tmp_path / "skew.yaml"
    f.write_text("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n"
                 "   dt: d\n   data: [ 500., 4., 320., 0., 500., 240., 0., 0., 1. ]\n"
                 "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n"
                 "   dt: d\n   data: [ 0., 0., 0., 0., 0. ]\n")
    with pytest.raises(CameraFileError) as e:
        load_camera(f)
    msg = str(e.value)
    assert "\n" not in msg and str(f) in msg and "camera_matrix" in msg
    assert "skew" in msg and "zero skew" in msg
    K = Camera.drone_webcam().K.copy()
    K[0, 1] = 4.0
    with pytest.raises(ValueError, match="skew"):
        Camera(K, np.zeros(5), 640, 480)


def test_scaled_keeps_pixel_centre_convention():
    cam = Camera.drone_webcam()
    half = cam.scaled(320, 240)
    assert half.fx == pytest.approx(cam.fx / 2)
    # pixel centres: x' = (x + 0.5)/2 − 0.5, so the same 3D point lands at the scaled pixel
    p = np.array([[0.3, -0.2, 2.0], [-0.4, 0.25, 1.5]])
    np.testing.assert_allclose(half.project(p), (cam.project(p) + 0.5) / 2 - 0.5, atol=1e-9)
    assert cam.scaled(640, 480).almost_equal(cam)
    assert cam.hfov_deg() == pytest.approx(60.0, abs=0.01)


@pytest.mark.parametrize("content,needle", [
    (None, "not found"),
    ("%YAML:1.0\n---\nimage_width: 640\n", "camera_matrix: missing"),
    ("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
     "   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\n", "distortion_coefficients"),
    ("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 2\n   cols: 2\n   dt: d\n"
     "   data: [ 500., 0., 0., 500. ]\ndistortion_coefficients: !!opencv-matrix\n   rows: 1\n"
     "   cols: 5\n   dt: d\n   data: [ 0., 0., 0., 0., 0. ]\n", "3x3"),
    ("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
     "   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\ndistortion_coefficients: "
     "!!opencv-matrix\n   rows: 1\n   cols: 3\n   dt: d\n   data: [ 0., 0., 0. ]\n",
     "3 coefficients"),
    ("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
     "   data: [ 500., 0., 320., 0., 500., 240. ]\n", "camera_matrix: rows x cols = 3x3 but data"),
    ("{\"camera_matrix\": [1, 2", "invalid JSON"),
    ("hello: [1, 2\n", "not valid YAML"),
    ("just: text\n", "not a camera file"),
    ("camera_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 2, 3]\n", "rows x cols"),
    ("camera_matrix:\n  rows: 3\n  cols: 3\n  data: [500, 0, 320, 0, 500, 240, 0, 0, 1]\n"
     "distortion_model: kannala_brandt_8\ndistortion_coefficients:\n  rows: 1\n  cols: 4\n"
     "  data: [0, 0, 0, 0]\n", "distortion_model: 'kannala_brandt_8' is not a lens model"),
])
def test_bad_files_name_file_and_field(tmp_path: Path, content, needle):
    path = tmp_path / "bad_camera.yaml"
    if content is not None:
        path.write_text(content)
    with pytest.raises(CameraFileError) as err:
        load_camera(path)
    msg = str(err.value)
    assert "bad_camera.yaml" in msg and needle in msg, msg


def test_binary_file_is_refused(tmp_path: Path):
    path = tmp_path / "photo.yaml"
    path.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(CameraFileError, match="photo.yaml"):
        load_camera(path)


def test_ros_json_written_values_are_shortest_repr(tmp_path: Path):
    cam = awkward_camera(5)
    path = save_camera(cam, tmp_path / "c.ros.yaml", "ros")
    text = path.read_text()
    assert repr(cam.fy) in text and "distortion_model: plumb_bob" in text
    # and the OpenCV JSON form is plain JSON other tools can read
    data = json.loads(save_camera(cam, tmp_path / "c.json").read_text())
    assert data["camera_matrix"]["rows"] == 3


# ------------------------------------------------------------------ files other tools write

# The form of OpenCV's tutorial camera files (samples/cpp/tutorial_code/objectDetection): a
# 5x1 matrix, no image size, no camera name. Values: plain OpenCV calibration of the shared
# left views (../shared/datasets/opencv-left).
OPENCV_TUTORIAL_FORM = """%YAML:1.0
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 532.8, 0., 342.5,
       0., 532.9, 233.9,
       0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -0.281, 0.0249,
       0.00121, -0.000134, 0.159 ]
"""

# ROS camera_calibration's fisheye output names the model "equidistant" (Kalibr too).
ROS_EQUIDISTANT = """image_width: 1280
image_height: 800
camera_name: fisheye_cam
camera_matrix:
  rows: 3
  cols: 3
  data: [410.2, 0.0, 640.3, 0.0, 410.5, 399.1, 0.0, 0.0, 1.0]
distortion_model: equidistant
distortion_coefficients:
  rows: 1
  cols: 4
  data: [-0.012, 0.031, -0.021, 0.004]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [410.2, 0, 640.3, 0, 0, 410.5, 399.1, 0, 0, 0, 1, 0]
"""


def test_opencv_tutorial_file_without_size_takes_the_image_size(tmp_path: Path):
    (tmp_path / "tutorial_camera_params.yml").write_text(OPENCV_TUTORIAL_FORM)
    cam = load_camera(tmp_path / "tutorial_camera_params.yml")
    assert not cam.size_known and cam.model == "plumb_bob" and cam.dist.size == 5
    sized, note = cam.for_image(640, 480)            # a 640x480 photo: used as such
    assert sized.size == (640, 480) and note is None
    _, note = cam.for_image(1920, 1080)              # principal point far off-centre: said
    assert note is not None and "far from their centre" in note
    with pytest.raises(ValueError, match="1920x1080 but the camera file is for 640x480"):
        sized.for_image(1920, 1080)


def test_ros_equidistant_is_read_as_fisheye_and_round_trips(tmp_path: Path):
    (tmp_path / "ost.yaml").write_text(ROS_EQUIDISTANT)
    cam = load_camera(tmp_path / "ost.yaml")
    assert cam.model == "fisheye" and cam.is_fisheye and cam.size == (1280, 800)
    for fmt, name in ((None, "c.yaml"), ("ros", "c.ros.yaml"), (None, "c.xml"), ("json", "c.json")):
        back = load_camera(save_camera(cam, tmp_path / name, fmt))
        assert back.model == "fisheye" and back.almost_equal(cam), (fmt, name)
    assert "distortion_model: equidistant" in (tmp_path / "c.ros.yaml").read_text()
    # OpenCV's calibration sample flags a fisheye camera with fisheye_model: 1
    text = OPENCV_TUTORIAL_FORM.replace("   rows: 5\n   cols: 1", "   rows: 4\n   cols: 1") \
        .replace("0.00121, -0.000134, 0.159", "0.00121, -0.000134") + "fisheye_model: 1\n"
    (tmp_path / "fs.yml").write_text(text)
    assert load_camera(tmp_path / "fs.yml").is_fisheye


def test_fisheye_projection_matches_opencv_and_undistortion_inverts_it():
    cam = Camera.from_fov(1280, 800, 150.0, dist=[0.02, -0.01, 0.003, -0.0005],
                          model="fisheye")
    rng = np.random.default_rng(1)
    theta = rng.uniform(0, np.radians(74), 300)          # up to 148° across
    phi = rng.uniform(-np.pi, np.pi, 300)
    pts = np.c_[np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]
    ref, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros((3, 1)),
                                       np.zeros((3, 1)), cam.K, cam.dist)
    px = cam.project(pts)
    np.testing.assert_allclose(px, ref.reshape(-1, 2), atol=1e-9)
    rays = cam.rays(px)
    angle = np.arctan2(np.linalg.norm(np.cross(rays, pts), axis=1), np.sum(rays * pts, axis=1))
    assert np.degrees(angle).max() < 1e-7


@pytest.mark.parametrize("content,needle", [
    # an OpenCV size that is text, not a number (was read as 1.8e308)
    (OPENCV_SAMPLE_YAML.replace("image_width: 640", 'image_width: "abc"'),
     "image_width: 'abc' is not a whole number"),
    # a size that would allocate tens of GiB
    (OPENCV_SAMPLE_YAML.replace("image_width: 640", "image_width: 100000"), "image_width"),
    (ROS_SAMPLE_YAML.replace("image_width: 640", "image_width: abc"), "image_width"),
    # a principal point that no image has
    (OPENCV_TUTORIAL_FORM.replace("342.5,", "-999.,"), "principal point"),
    (OPENCV_SAMPLE_YAML.replace("3.4215652571342125e+02", "9.4215652571342125e+02"),
     "principal point"),
    (OPENCV_SAMPLE_YAML.replace("5.3280072497128633e+02", ".nan"), "camera_matrix"),
    (ROS_SAMPLE_YAML.replace("532.80072497128633", "-532.8"), "focal lengths"),
    (ROS_SAMPLE_YAML.replace("plumb_bob", "rational_polynomial"), "rational_polynomial needs"),
    (ROS_SAMPLE_YAML.replace("plumb_bob", "equidistant"), "fisheye (Kannala-Brandt) model has 4"),
    (ROS_SAMPLE_YAML.replace("plumb_bob", "radtan"), "'radtan' is not a lens model"),
    ("a: &a [1, 2]\n" + "".join(f"b{i}: &b{i} [*a, *a, *a]\n" for i in range(150)),
     "aliases"),
    ("[" * 5000 + "]" * 5000, "nested"),
])
def test_malformed_camera_files_are_one_line_naming_the_field(tmp_path: Path, content, needle):
    path = tmp_path / "camera.yaml"
    path.write_text(content)
    with pytest.raises(CameraFileError) as err:
        load_camera(path)
    msg = str(err.value)
    assert "camera.yaml" in msg and needle in msg and "\n" not in msg, msg


@pytest.mark.parametrize("key,count,needle", [
    ("camera_matrix", 50_000, "camera_matrix: expected 3x3 values, got 50000"),
    ("distortion_coefficients", 70, "distortion_coefficients: 70 coefficients; OpenCV's "
                                    "model has 4, 5, 8, 12 or 14"),
])
def test_a_matrix_of_thousands_of_values_says_how_many_and_what_is_expected(
        tmp_path: Path, key, count, needle):
    import json

    data = {"camera_matrix": [500.0, 0, 320, 0, 500, 240, 0, 0, 1],
            "distortion_coefficients": [0.0] * 5, key: [0.0] * count}
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(data))
    with pytest.raises(CameraFileError) as err:
        load_camera(path)
    assert str(err.value) == f"{path}: {needle}" + ("" if key == "camera_matrix" else
                                                     " (k1 k2 p1 p2 k3 ...)")


def test_a_loop_of_symbolic_links_is_said_as_one_not_as_a_missing_file(tmp_path: Path):
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    a.symlink_to(b)
    b.symlink_to(a)
    with pytest.raises(CameraFileError) as err:
        load_camera(a)
    assert str(err.value) == (f"{a}: the camera file is a loop of symbolic links (they lead "
                              "to each other, never to a file or folder); give the real path")


def test_a_pipe_is_not_read_as_a_camera_file(tmp_path: Path):
    import os

    fifo = tmp_path / "camera.yaml"
    os.mkfifo(fifo)
    with pytest.raises(CameraFileError, match="not a regular file"):
        load_camera(fifo)               # returns at once: a FIFO is never opened


def _alias_bomb(levels: int = 6) -> str:
    """Aliases of aliases, under the alias cap (9 a level): nine to the ``levels`` values."""
    lines = ["a0: &a0 [0, 0, 0, 0, 0, 0, 0, 0, 0]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]"
              for i in range(1, levels)]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("tail", [
    # quoted in the error of a matrix value, or of the lens model: the whole expansion
    # was written out first (ten levels: billions of values, never finished)
    "camera_matrix: [*a5, 0, 320, 0, 500, 240, 0, 0, 1]\ndistortion_coefficients: [0, 0, 0, 0]\n",
    "camera_matrix: [[500, 0, 320], [0, 500, 240], [0, 0, 1]]\n"
    "distortion_coefficients: [0, 0, 0, 0]\nfisheye_model: 1\ndistortion_model: *a5\n",
])
def test_a_yaml_alias_bomb_under_the_alias_cap_is_refused_by_what_it_expands_to(
        tmp_path: Path, tail: str):
    path = tmp_path / "camera.yaml"
    path.write_text(_alias_bomb() + tail)
    with pytest.raises(CameraFileError) as err:
        load_camera(path)
    assert str(err.value) == (
        f"{path}: its YAML aliases expand to more than 100,000 values (an alias bomb?); write "
        "the values out instead; expected an OpenCV or ROS camera file")


def test_a_yaml_alias_that_holds_itself_is_refused(tmp_path: Path):
    path = tmp_path / "camera.yaml"
    path.write_text("camera_matrix: &m [1, *m]\ndistortion_coefficients: [0, 0, 0, 0]\n")
    with pytest.raises(CameraFileError) as err:
        load_camera(path)
    assert str(err.value) == (f"{path}: a YAML alias holds itself (a loop); write the values "
                              "out instead; expected an OpenCV or ROS camera file")


def test_a_few_aliases_are_still_read(tmp_path: Path):
    path = tmp_path / "camera.yaml"
    path.write_text("z: &z 0.0\nrow: &r [0, 0, 1]\ncamera_matrix: [[500, *z, 320], "
                    "[0, 500, 240], *r]\ndistortion_coefficients: [*z, *z, *z, *z]\n")
    assert load_camera(path).K[2].tolist() == [0.0, 0.0, 1.0]
