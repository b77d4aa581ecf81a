"""`drovisio run` on the sample approach video: JSON Lines and UDP carry the poses (vs truth)."""

from __future__ import annotations

import json
import socket
import threading
import time
from pathlib import Path

import numpy as np

from drovisio.cli import main
from drovisio.fusion import so3_exp

REPO = Path(__file__).resolve().parents[2]
APPROACH = REPO / "sample_sessions" / "approach"
LAYOUTS = [REPO / "marker_layouts" / f"{n}.json"
           for n in ("drick-aruco-pyramids", "drick-aruco-centre", "drick-dots-2x3")]


def truth_by_frame() -> dict[int, list[dict]]:
    out = {}
    for line in (APPROACH / "truth.jsonl").read_text().splitlines():
        d = json.loads(line)
        out[d["frame"]] = d["bricks"]
    return out


def match_truth(brick: dict, truth: list[dict]) -> dict | None:
    if brick["instance"] is not None:
        c = [t for t in truth if t["layout"] == brick["layout"]
             and t["instance"] == brick["instance"]]
    else:
        c = sorted((t for t in truth if t["layout"] == brick["layout"]),
                   key=lambda t: np.linalg.norm(np.subtract(t["tvec"], brick["tvec"])))
    return c[0] if c else None


def test_run_sample_video_jsonl_and_udp(tmp_path):
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.5)
    port = rx.getsockname()[1]
    datagrams: list[bytes] = []
    stop = threading.Event()

    def listen():
        while not stop.is_set():
            try:
                datagrams.append(rx.recv(65536))
            except TimeoutError:
                pass

    th = threading.Thread(target=listen, daemon=True)
    th.start()
    out = tmp_path / "poses.jsonl"
    args = ["run", "--source", str(APPROACH / "approach.mp4"),
            "--camera", str(REPO / "sample_sessions" / "camera.yaml"),
            "--mount", str(APPROACH / "mount.json"), "--sink", f"jsonl:{out}",
            "--sink", f"udp://127.0.0.1:{port}", "--pace", "max", "--quiet"]
    for lay in LAYOUTS:
        args += ["--layout", str(lay)]
    assert main(args) == 0
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    # every datagram is sent by now; the listener may still be reading them (waited for:
    # the bound is for failures only)
    end = time.monotonic() + 60
    while len(datagrams) < len(lines) and time.monotonic() < end:
        time.sleep(0.01)
    stop.set()
    th.join(60)
    rx.close()

    assert [d["frame"] for d in lines] == list(range(150))  # --pace max: every frame
    udp = [json.loads(d) for d in datagrams]
    assert [d["frame"] for d in udp] == [d["frame"] for d in lines]
    assert udp[10] == lines[10]  # same object on both sinks

    truth = truth_by_frame()
    mount = json.loads((APPROACH / "mount.json").read_text())["body_from_camera"]
    B = np.asarray(mount)
    errs, body_errs, n_bricks = [], [], []
    for d in lines:
        n_bricks.append(sum(b["measured"] for b in d["bricks"]))
        for b in d["bricks"]:
            assert b["t"] == d["t"] and 0 <= b["age"] <= 0.5
            t = match_truth(b, truth[d["frame"]])
            assert t is not None, (d["frame"], b["layout"], b["instance"])
            if not b["measured"]:
                continue
            errs.append(np.linalg.norm(np.subtract(b["tvec"], t["tvec"])))
            p_body = B[:3, :3] @ np.asarray(t["tvec"]) + B[:3, 3]
            body_errs.append(np.linalg.norm(np.subtract(b["body_from_brick"]["tvec"], p_body)))
            R_err = so3_exp(b["rvec"]).T @ so3_exp(t["rvec"])
            if b["layout"] != "drick-dots-2x3":  # symmetric: yaw only up to a half-turn
                assert np.degrees(np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1, 1))) < 10
    errs, body_errs = np.array(errs), np.array(body_errs)
    # all five bricks at the start, always at least one until the markers leave the view
    assert n_bricks[0] == 5 and min(n_bricks[:120]) >= 1
    assert np.median(errs) < 0.02 and np.percentile(errs, 95) < 0.05
    assert np.allclose(np.median(errs), np.median(body_errs), atol=0.005)
    print(f"\n{len(errs)} measured poses: median position error {1000 * np.median(errs):.1f} mm,"
          f" 95% {1000 * np.percentile(errs, 95):.1f} mm")
