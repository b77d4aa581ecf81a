"""Code acceptance, ambiguity and identity on real photos nobody here rendered
(``../shared/datasets/real``: its README names each set's source).

Skipped with the reason when the folder is absent; ``DROVISIO_REQUIRE_SHARED=1`` (CI) makes
its absence a failure.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio.bench.real import charuco_layout, tag_layout
from drovisio.bench.real_measures import APRILTAG_PIXEL_OFFSET
from drovisio.bench.real_measures import match_corners as _match_corners
from drovisio.camera_file import load_camera
from drovisio.detect.aruco import ArucoBrickDetector

REPO_ROOT = Path(__file__).resolve().parents[2]
REAL = Path(os.environ.get("DROVISIO_REAL_DATA", REPO_ROOT.parent / "shared" / "datasets" /
                           "real"))


def _need(sub: str) -> Path:
    """The real set ``sub`` of ``../shared`` (the skip says why; CI fails instead)."""
    d = REAL / sub
    if not d.is_dir():
        msg = (f"real data {d} is absent; set DROVISIO_REAL_DATA to the folder of "
               "../shared/datasets/real to run these tests")
        if os.environ.get("DROVISIO_REQUIRE_SHARED") == "1":  # CI has it
            pytest.fail(msg)
        pytest.skip(msg)
    return d


@pytest.fixture(scope="module")
def charuco():
    d = _need("charuco")
    dic = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    board = cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02, dic)
    cam = load_camera(d / "tutorial_camera_charuco.yml").for_image(640, 480)[0]
    gray = cv2.imread(str(d / "choriginal.jpg"), cv2.IMREAD_GRAYSCALE)
    cc, ci, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
    obj = np.asarray(board.getChessboardCorners(), np.float64)[np.ravel(ci)]
    ok, rv, tv = cv2.solvePnP(obj, cc, cam.K, cam.dist)
    assert ok and len(ci) == 24
    return {"board": board, "camera": cam, "gray": gray, "rvec": rv, "tvec": tv}


def _board_prediction(ch, marker_id: int) -> np.ndarray:
    b = ch["board"]
    k = list(np.ravel(b.getIds())).index(marker_id)
    p, _ = cv2.projectPoints(np.asarray(b.getObjPoints()[k], np.float64), ch["rvec"],
                             ch["tvec"], ch["camera"].K, ch["camera"].dist)
    return p.reshape(4, 2)


def test_charuco_tutorial_photo_keeps_every_code_opencv_reads(charuco):
    """OpenCV reads 17 codes; the fixed 0.25 cell margin dropped 4 of them (margins 0.15 -
    0.24 in a real JPEG). Each is kept; its corners sit nearer the board pose's prediction
    than OpenCV's; the 17-code brick is posed like OpenCV's ChArUco board."""
    det = ArucoBrickDetector(charuco["camera"], [charuco_layout(charuco["board"],
                                                                "DICT_6X6_250")])
    poses = det.detect(charuco["gray"])
    _, cv_ids, _ = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)).detectMarkers(charuco["gray"])
    kept = sorted(c.marker_id for c in det.last_codes if c.refined.ok)
    assert kept == sorted(int(i) for i in np.ravel(cv_ids)) == list(range(17))
    assert len(poses) == 1 and poses[0].markers == list(range(17))
    ours = np.concatenate([np.linalg.norm(c.refined.corners_px
                                          - _board_prediction(charuco, c.marker_id), axis=1)
                           for c in det.last_codes])
    cv_c, cv_i, _ = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)).detectMarkers(charuco["gray"])
    theirs = np.concatenate([np.linalg.norm(np.asarray(q).reshape(4, 2)
                                            - _board_prediction(charuco, int(i)), axis=1)
                             for q, i in zip(cv_c, np.ravel(cv_i))])
    # measured: median 0.38 px, p90 0.71 (OpenCV's corners 1.03 px; from the code's
    # interior alone, without its outer edges against the paper around it, 0.68 px)
    assert np.median(ours) < 0.5 and np.median(ours) < 0.5 * np.median(theirs)
    # against a reading that assumes nothing of the board: AprilTag 3 with the board's
    # dictionary as its family reads the same 17 codes; each of Drovisio's is within 0.5 px
    # RMS of its corners (0.33 median, 0.46 at most)
    from drovisio.study.apriltag import apriltag_reader

    at = {c.marker_id: c.corners for c in apriltag_reader("DICT_6X6_250").detect(
        charuco["gray"])}
    assert sorted(at) == kept
    rms = [float(np.sqrt(np.mean(np.sum((c.refined.corners_px - at[c.marker_id]) ** 2, 1))))
           for c in det.last_codes]
    assert max(rms) < 0.5 and np.median(rms) < 0.4
    b = poses[0]
    R = cv2.Rodrigues(np.ravel(b.rvec))[0] @ np.diag([1.0, -1.0, -1.0])  # brick y, z flipped
    Rb = cv2.Rodrigues(charuco["rvec"])[0]
    angle = np.degrees(np.arccos(np.clip((np.trace(R.T @ Rb) - 1) / 2, -1, 1)))
    assert np.linalg.norm(np.ravel(b.tvec) - charuco["tvec"].ravel()) < 0.002   # 0.88 mm
    assert angle < 0.2                                                          # 0.065°


def test_a_small_code_alone_is_flagged_where_its_noise_cannot_tell_its_mirror(charuco):
    """Each of the board's 17 codes (2 cm, 23-31 px) posed alone: the fit's pixel noise
    said its corners were good to 0.055 px, yet they lie 0.23 px per coordinate from
    AprilTag 3's (median) and one pose came out 38 degrees off the board's, its mirror,
    decided and unflagged. With half the distance between the fits with and without the
    outer edges in the corners' covariance (0.27 px, with the residuals' correlation), no pose
    is both off and unflagged, and the corners lie within about one of their standard
    deviations of AprilTag's (0.78, the median ratio; 3.8 before)."""
    from drovisio.study.apriltag import apriltag_reader

    det = ArucoBrickDetector(charuco["camera"], [tag_layout("DICT_6X6_250", 0.02)])
    poses = det.detect(charuco["gray"])
    assert len(poses) == 17
    b = charuco["board"]
    ids = list(np.ravel(b.getIds()))
    Rb = cv2.Rodrigues(charuco["rvec"])[0]
    for p in poses:   # the code's frame: the board's with y and z flipped (printed up, out)
        R = cv2.Rodrigues(np.ravel(p.rvec))[0] @ np.diag([1.0, -1.0, -1.0])
        angle = np.degrees(np.arccos(np.clip((np.trace(R.T @ Rb) - 1) / 2, -1, 1)))
        assert p.ambiguous or angle < 20, (p.instance, angle)
        centre = np.asarray(b.getObjPoints()[ids.index(p.instance)], np.float64).mean(0)
        assert np.linalg.norm(np.ravel(p.tvec) - (Rb @ centre + charuco["tvec"].ravel())) < 0.01
    at = {c.marker_id: c.corners for c in apriltag_reader("DICT_6X6_250").detect(
        charuco["gray"])}
    z = [np.sqrt(np.mean((c.refined.corners_px - at[c.marker_id]) ** 2)) / c.refined.sigma_px
         for c in det.last_codes]
    assert len(z) == 17 and np.median(z) < 2.0        # measured 0.78 (3.8 before)


@pytest.mark.parametrize("codes", [13, 17])
def test_rigid_board_is_not_ambiguous(charuco, codes):
    """The board's mirror pose reprojects ~20 px RMS worse: χ² at the corners' assumed
    noise (417 for 52 corners) exceeded 3·dof + 4, real JPEG corners being noisier than
    their fit says; the noise measured robustly in the board's own residuals decides it."""
    lay = charuco_layout(charuco["board"], "DICT_6X6_250")
    if codes == 13:  # the four codes the fixed cell margin used to drop
        lay = lay.model_copy(update={"markers": [m for m in lay.markers
                                                 if m.id not in (1, 3, 7, 15)]})
    det = ArucoBrickDetector(charuco["camera"], [lay])
    poses = det.detect(charuco["gray"])
    assert len(poses) == 1 and len(poses[0].markers) == codes
    res = det.last_results[("charuco", 0)]
    assert not poses[0].ambiguous and res.decided_by == "reprojection"
    worse = sorted(c.rmse_px for c in res.candidates)
    assert worse[1] > 10 * worse[0]


def _tag_photos(paths: list[Path], camera_file: Path, flag: int = cv2.IMREAD_COLOR) -> dict:
    """Each tag36h11 photo read by Drovisio, plain OpenCV and AprilTag 3, by file name:
    poses, codes, the ids read more than once, and the peers' (id, corners) in OpenCV's
    pixel convention."""
    from drovisio.study.methods import apriltag_detector

    det = ArucoBrickDetector(load_camera(camera_file),
                             [tag_layout("DICT_APRILTAG_36h11", 0.065)])
    cv_det = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11))
    out = {}
    for f in paths:
        img = cv2.imread(str(f), flag)
        g = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        poses = det.detect(img)
        q, i, _ = cv_det.detectMarkers(g)
        out[f.name] = {"poses": poses, "codes": list(det.last_codes),
                       "duplicates": dict(det.last_duplicates),
                       "opencv": [(int(k), np.asarray(c).reshape(4, 2))
                                  for c, k in zip(q, np.ravel(i))],
                       "apriltag": [(int(a.tag_id), a.corners - APRILTAG_PIXEL_OFFSET)
                                    for a in apriltag_detector("tag36h11").detect(g)]}
    return out


@pytest.fixture(scope="module")
def multi():
    d = _need("apriltag-multi")
    return _tag_photos(sorted(d.glob("*.png")), d / "camera.yaml", cv2.IMREAD_GRAYSCALE)


def _near(q, pool):
    side = np.linalg.norm(q[1] - q[0])
    return [p for p in pool if np.linalg.norm(p.mean(axis=0) - q.mean(axis=0)) < 0.3 * side]


def test_multi_tag_photos_codes_kept_and_corners_agree_with_apriltag(multi):
    ok_codes = kept = n_cv = 0
    rms = []
    missed = []
    for name, r in multi.items():
        good = [c for c in r["codes"] if c.refined.ok]
        ok_codes += len(good)
        for c in good:  # no false code: each is one a peer reads at that place
            q = c.refined.corners_px
            assert (_near(q, [p for i, p in r["opencv"] if i == c.marker_id])
                    or _near(q, [p for i, p in r["apriltag"] if i == c.marker_id])), name
            at = _near(q, [p for i, p in r["apriltag"] if i == c.marker_id])
            if at:
                rms.append(float(np.sqrt(np.mean(_match_corners(q, at[0]) ** 2))))
        for mid, q in r["opencv"]:
            n_cv += 1
            got = bool(_near(q, [c.refined.corners_px for c in good if c.marker_id == mid]))
            kept += got
            missed += [] if got else [f"{name}:{mid}"]
        # every brick is one code, posed (a fit worse than 2 px is kept when OpenCV's own
        # corners fit the camera no better)
        assert sorted(p.markers[0] for p in r["poses"]) == sorted(c.marker_id for c in good)
    # every code OpenCV reads is kept (one, tag 85 of 07, at its outer edge lines: next test)
    assert n_cv == 54 and kept == 54 and ok_codes == 56
    assert missed == []
    rms_a = np.array(rms)
    # measured: median 0.14 px, p90 0.31 px, max 1.03 px, 54 of 56 within 0.5 px (OpenCV's
    # corners: 0.81, 1.44; from the codes' interior alone, without their outer edges: 0.19,
    # 0.53, 48 of 55). The two beyond: a 25-px tag on a bent card seen at a grazing angle
    # (1.03 px) and a 19-px tag whose one-cell white ring meets a dark ground (0.51 px)
    assert np.median(rms_a) < 0.2 and np.percentile(rms_a, 90) < 0.35
    assert np.sum(rms_a < 0.5) >= 54 and rms_a.max() < 1.2


def test_codes_of_twelve_pixels_opencv_reads_are_kept(multi):
    """Two 36h11 codes of ~12 px (cells 1.5 px) that OpenCV's default pass reads: the
    smallest code side is that of the code, while OpenCV's perimeter limit measures its
    contour, a pixel and a half shorter a side; both are kept, their corners near
    AprilTag's."""
    for name, mid in [("test_image_multiple_06.png", 24), ("test_image_multiple_10.png", 85)]:
        r = multi[name]
        c = [c for c in r["codes"] if c.marker_id == mid and c.refined.ok]
        assert len(c) == 1, name
        q = c[0].refined.corners_px
        assert 10.0 < np.linalg.norm(q[1] - q[0]) < 14.0
        at = _near(q, [p for i, p in r["apriltag"] if i == mid])
        # measured: RMS 0.34 px (12.7-px code) and 0.67 px (11.7 px)
        assert np.sqrt(np.mean(_match_corners(q, at[0]) ** 2)) < 1.0, name
        assert mid in [p.markers[0] for p in r["poses"]]


def test_a_code_whose_interior_is_no_square_of_its_border_is_kept_at_its_edges(multi):
    """On test_image_multiple_07 the 95-px tag 85 at the rim of the (already undistorted)
    photo: its cells are no homography of its outer border there (the border is half a cell
    thinner than the cells say), so the interior fit, extrapolated, puts a corner 11 px onto
    the paper and is not taken. Its outer edge lines meet within 0.5 px RMS of AprilTag's
    corners and its cells read right there: the code is kept at its edges, its covariance
    holding the two readings' disagreement."""
    r = multi["test_image_multiple_07.png"]
    c85 = [c for c in r["codes"] if c.marker_id == 85]
    assert len(c85) == 1 and c85[0].refined.ok and c85[0].refined.edge_lines
    at = [p for i, p in r["apriltag"] if i == 85][0]
    d = _match_corners(c85[0].refined.corners_px, at)
    # measured: RMS 0.24 px, the rim corner 0.40 px; sigma 1.5 px per coordinate
    assert np.sqrt(np.mean(d ** 2)) < 0.5 and d.max() < 0.8
    assert c85[0].refined.sigma_px > 1.0
    assert 85 in [p.markers[0] for p in r["poses"]]
    # the 82-px tag 198 (fit 3.9 px RMS, OpenCV's corners 3.6 px: the camera's) is kept
    assert 198 in [p.markers[0] for p in r["poses"]]
    # no other code of the set needed its edges
    assert sum(c.refined.edge_lines for v in multi.values() for c in v["codes"]) == 1


SWARM = REPO_ROOT / "tests" / "data" / "real" / "apriltag-swarm"


def _expected_corners(txt: Path) -> list[np.ndarray]:
    """AprilTag's expected corners (its test data), in OpenCV's pixel convention."""
    import re

    return [np.array([[float(a), float(b)] for a, b in re.findall(r"\(([-\d.]+) ([-\d.]+)\)", ln)])
            - APRILTAG_PIXEL_OFFSET for ln in txt.read_text().splitlines() if ln.strip()]


@pytest.fixture(scope="module")
def swarm():
    out = _tag_photos(sorted(SWARM.glob("*.jpg")), SWARM / "camera.yaml")
    for name, r in out.items():
        r["expected"] = _expected_corners(SWARM / Path(name).with_suffix(".txt").name)
    return out


def test_many_codes_with_one_id_are_posed_each_and_flagged(swarm):
    """AprilTag's Swarmathon photos: cubes with tag 0 on every face. Each copy is its own
    pose, flagged duplicate; none is merged into one brick."""
    for name, r in swarm.items():
        poses = r["poses"]
        good = [c for c in r["codes"] if c.refined.ok]
        assert len(good) >= 10
        assert len(poses) == len(good) and all(p.duplicate for p in poses)
        assert all(p.markers == [0] and len(p.image_points) == 4 for p in poses)
        assert all(p.to_json()["duplicate"] is True for p in poses)
        assert r["duplicates"] == {0: len(good)}
        centres = np.array([p.image_points.mean(axis=0) for p in poses])
        gaps = np.linalg.norm(centres[:, None] - centres[None], axis=2) + np.eye(len(poses)) * 1e9
        assert gaps.min() > 5.0, name   # distinct codes, not one read twice


def test_swarm_photos_codes_kept_and_corners_agree_with_apriltag(swarm):
    """A downscaled, sharpened Flickr JPEG: every code read is the tag 0 the cubes carry
    (all 587 ids of the dictionary are live, so a false reading would show another id); of
    the codes OpenCV reads, those kept and their corners against AprilTag's expected ones."""
    kept = n_cv = 0
    rms: dict[str, list[float]] = {"expected": [], "apriltag": []}
    for name, r in swarm.items():
        good = [c for c in r["codes"] if c.refined.ok]
        assert {c.marker_id for c in good} == {0}, name
        for mid, q in r["opencv"]:
            assert mid == 0
            n_cv += 1
            kept += bool(_near(q, [c.refined.corners_px for c in good]))
        for ref in rms:
            for t in ([p for _, p in r["apriltag"]] if ref == "apriltag" else r[ref]):
                m = _near(t, [c.refined.corners_px for c in good])
                if m:
                    rms[ref].append(float(np.sqrt(np.mean(_match_corners(m[0], t) ** 2))))
    # measured: OpenCV reads 42 codes, Drovisio keeps 38 (37 with a fixed limit of a fifth
    # of the contrast on the fit's residual); the 4 it has no quad for: two edge-on top
    # faces AprilTag does not read either, a 30-px side face whose border OpenCV bends, a
    # 39-px code in shadow
    assert n_cv == 42 and kept >= 38
    # corner RMS per code, measured: against AprilTag 3 (decimate 1, edges refined) 39
    # codes, median 0.30 px, p90 0.56, max 0.95; against the expected corners of AprilTag's
    # own test (its quads' edges not refined) 42 codes, median 0.47, p90 0.80
    at, ex = np.array(rms["apriltag"]), np.array(rms["expected"])
    assert len(at) >= 38 and np.median(at) < 0.35 and np.percentile(at, 90) < 0.65
    assert at.max() < 1.1
    assert len(ex) >= 40 and np.median(ex) < 0.55 and np.percentile(ex, 90) < 0.9


def test_a_code_whose_cells_read_right_is_kept_in_a_sharpened_jpeg(swarm):
    """The 16-px side face at (622, 284) of the second photo: its fit's residual is 0.26 of
    its contrast (the sharpening's halos, which no blurred model has), its cells read as tag
    0 with the classes 7.9 spreads apart and its corners stay where they started. A fixed
    limit of a fifth of the contrast refused it; it is kept, near AprilTag's corners."""
    r = swarm["34085369442_304b6bafd9_c.jpg"]
    c = [c for c in r["codes"] if np.linalg.norm(c.refined.corners_px.mean(0) - [622, 284]) < 3]
    assert len(c) == 1 and c[0].refined.ok, [x.refined.reason for x in c]
    assert c[0].refined.residual > 0.2 * c[0].refined.contrast
    at = _near(c[0].refined.corners_px, [p for _, p in r["apriltag"]])
    assert at and np.sqrt(np.mean(_match_corners(c[0].refined.corners_px, at[0]) ** 2)) < 1.0

