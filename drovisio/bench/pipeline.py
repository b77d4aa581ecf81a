"""``drovisio bench pipeline``: latency capture → sent, and resident memory over a long run.

Both use the real pipeline of ``drovisio run`` (ArUco + dot detectors, the three drick layouts,
the sample camera and mount, tracking, fusion) on the sample approach video, looped.

``latency`` — the video is played *as a 30 fps camera* (``--fps``; the frames of the 15 fps
file are handed over every 1/30 s, newest-frame policy), for ``--seconds``, with sinks
JSON Lines (to a file), UDP and MAVLink ``udpout`` to a pymavlink listener on loopback.
Reports, per processed frame, the latency from capture (the moment the frame was handed
over) to the moment every sink had sent its message, and, on the listener's side, capture →
``LANDING_TARGET`` received (its ``time_usec`` is the capture time). Pass: median ≤ one frame
interval (33.3 ms at 30 fps).

``memory`` — ``--minutes`` of 30 fps stream time (36 000 frames for 20 minutes), **run
accelerated**: frames are processed back to back without waiting for the camera clock
(``pace="max"``), but time-stamped on the stream's own 30 fps clock, so that tracking, ages and
dropping behave as in real time. All four sink kinds are open (JSON Lines to /dev/null, UDP to a
port nobody listens on, MAVLink ``udpout`` with nobody answering, a WebSocket feed). Resident
memory (VmRSS) is sampled every second of stream time; growth = median RSS of the last
minute − median RSS of the minute after the warm-up (``--warmup-minutes``, default 2), and the
least-squares slope after warm-up. Pass: growth ≤ 1 MB.

``wire`` — measured **from outside the process**, as an integrator would check it: a network
MJPEG camera (an HTTP server in this process) plays the sample approach video at 30 fps into
``drovisio run --source http://... --sink mavlink:udpout:...`` (a separate process), and a
pymavlink listener takes each LANDING_TARGET's arrival time. Each message is matched to the
frame it describes (the frame, among those sent, whose true target position in the drone's
body frame the message's x, y, z fits best); its wire-to-message latency runs from the moment
that frame's last byte left the camera to the message's arrival. Also counted: messages whose
best frame is not the one they are stamped with (a held-over target would be one). Pass:
p90 ≤ 50 ms.

Examples::

    drovisio bench pipeline wire --seconds 20
    drovisio bench pipeline latency --seconds 20
    drovisio bench pipeline memory --minutes 20
    drovisio bench pipeline memory --minutes 2 --warmup-minutes 0.5   # quick look
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from drovisio._threads import join_thread
from drovisio.bounds import ArgumentParser, number
from drovisio.fileio import atomic_write_text
from drovisio.geometry import from_rvec_tvec
from drovisio.mount import load_mount
from drovisio.pipeline import Pipeline
from drovisio.pipeline_config import PipelineConfig
from drovisio.resources import layouts_dir, sample_sessions_dir
from drovisio.sinks.mavlink import mavutil2
from drovisio.sources import FrameSource, Pace, VideoFileReader
from drovisio.startup import build_pipeline

__all__ = ["main", "rss_mb"]

SAMPLE = sample_sessions_dir()
APPROACH = SAMPLE / "approach"
LAYOUTS = [layouts_dir() / f"{n}.json"
           for n in ("drick-aruco-pyramids", "drick-aruco-centre", "drick-dots-2x3")]


def rss_mb() -> float:
    """Resident set size of this process, MB (from /proc; 0 where unavailable)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
    except (OSError, ValueError, IndexError):
        return 0.0


class _AtFps:
    """Wraps a reader so that its frames are timed at ``fps`` (a 15 fps file as a 30 fps
    camera)."""

    def __init__(self, reader, fps: float):
        self.r = reader
        self.fps = fps
        self.label = f"{reader.label} @ {fps:g} fps"
        self.finite = reader.finite
        self.k = 0

    def open(self) -> None:
        self.r.open()

    def read(self):
        f = self.r.read()
        if f is not None:
            f.media_time = self.k / self.fps
            self.k += 1
        return f

    def close(self) -> None:
        self.r.close()


def _config(sinks: list[str]) -> PipelineConfig:
    """``drovisio run`` on the sample approach video with the three drick layouts."""
    return PipelineConfig(source=str(APPROACH / "approach.mp4"),
                          camera=str(SAMPLE / "camera.yaml"),
                          layouts=[str(x) for x in LAYOUTS], mount=str(APPROACH / "mount.json"),
                          sinks=sinks, record=None, target="nearest",
                          autopilot="ardupilot", max_age=0.5, pace="realtime")


def _pipeline(sinks: list[str], fps: float, pace: Pace) -> Pipeline:
    p = build_pipeline(_config(sinks))
    p.source = FrameSource(_AtFps(VideoFileReader(APPROACH / "approach.mp4", loop=True), fps),
                           pace=pace)
    return p


def _pct(a, q: float) -> float:
    return float(np.percentile(a, q)) if len(a) else float("nan")


def bench_latency(fps: float, seconds: float) -> dict:
    mavutil = mavutil2()
    rx = mavutil.mavlink_connection("udpin:127.0.0.1:0")
    port = rx.port.getsockname()[1]
    got: list[float] = []
    stop = threading.Event()

    def listen() -> None:
        while not stop.is_set():
            m = rx.recv_match(type="LANDING_TARGET", blocking=True, timeout=0.1)
            if m is not None:
                got.append(time.time() - m.time_usec / 1e6)

    th = threading.Thread(target=listen, daemon=True)
    th.start()
    lat: list[float] = []
    det: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        p = _pipeline([f"jsonl:{Path(tmp) / 'out.jsonl'}", f"udp://127.0.0.1:{port + 1}",
                       f"mavlink:udpout:127.0.0.1:{port}"], fps, "realtime")

        def on_frame(frame, out) -> None:
            if frame is not None:
                lat.append((time.monotonic() - frame.t_read) * 1e3)
                det.append(out.detect_ms)

        p.add_listener(on_frame)
        th_run = threading.Thread(target=p.run, daemon=True)
        th_run.start()
        time.sleep(seconds)
        p.stop()
        join_thread(th_run, "running the benchmark's pipeline")
        st = p.snapshot()
        p.close()
    stop.set()
    join_thread(th, "listening for LANDING_TARGET")   # each read waits 0.1 s at most
    rx.close()
    lat_a = np.array(lat[int(fps):])  # first second: warm-up
    rx_a = np.array(got[int(fps):]) * 1e3
    frames_offered = st.source.frames
    return {
        "fps_camera": fps, "seconds": seconds, "frames_offered": frames_offered,
        "frames_processed": st.frames, "frames_dropped": st.source.dropped,
        "processed_fps": round(st.frames / seconds, 2),
        "latency_ms": {"median": round(_pct(lat_a, 50), 2), "p90": round(_pct(lat_a, 90), 2),
                       "max": round(float(lat_a.max()) if len(lat_a) else float("nan"), 2)},
        "capture_to_received_ms": {"median": round(_pct(rx_a, 50), 2),
                                   "p90": round(_pct(rx_a, 90), 2), "n": len(rx_a)},
        "detect_ms_median": round(_pct(det, 50), 2),
        "budget_ms": round(1000 / fps, 2),
        "pass": bool(len(lat_a) and _pct(lat_a, 50) <= 1000 / fps),
    }


class MjpegCamera:
    """A network camera: ``GET /stream.mjpg`` answers ``multipart/x-mixed-replace`` JPEG
    frames at ``fps`` (looping over ``jpegs``); the time each frame's last byte was handed to
    the socket is recorded per frame index."""

    def __init__(self, jpegs: list[bytes], fps: float, order: list[int] | None = None):
        self.jpegs = jpegs
        self.order = order or list(range(len(jpegs)))
        self.fps = fps
        self.sent: list[tuple[int, float]] = []        # (frame index in jpegs, UNIX time)
        self.stop = threading.Event()
        self._conn: socket.socket | None = None
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(2)
        self.port = self.sock.getsockname()[1]
        self.thread = threading.Thread(target=self._serve, daemon=True, name="mjpeg-camera")
        self.thread.start()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/stream.mjpg"

    def _serve(self) -> None:
        self.sock.settimeout(0.5)
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except (TimeoutError, OSError):
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._conn = conn
            try:
                conn.recv(4096)
                conn.sendall(b"HTTP/1.0 200 OK\r\nContent-Type: multipart/x-mixed-replace; "
                             b"boundary=frame\r\nCache-Control: no-cache\r\n\r\n")
                k = 0
                t_next = time.monotonic()
                while not self.stop.is_set():
                    i = self.order[k % len(self.order)]
                    data = self.jpegs[i]
                    conn.sendall(b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: "
                                 + str(len(data)).encode() + b"\r\n\r\n" + data + b"\r\n")
                    self.sent.append((i, time.time()))
                    k += 1
                    t_next += 1.0 / self.fps
                    time.sleep(max(0.0, t_next - time.monotonic()))
            except OSError:
                pass
            finally:
                conn.close()

    def close(self) -> None:
        self.stop.set()
        self.sock.close()
        conn = self._conn
        if conn is not None:   # a send to a client that stopped reading would wait for ever
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
        join_thread(self.thread, "serving the MJPEG test camera")


def _body_truth() -> list[np.ndarray]:
    """Per frame of the sample video: the true body-frame positions (B, 3) of its bricks."""
    mount = load_mount(APPROACH / "mount.json")
    out = []
    for line in (APPROACH / "truth.jsonl").read_text().splitlines():
        rec = json.loads(line)
        out.append(np.array([mount.body_from(from_rvec_tvec(b["rvec"], b["tvec"]))[:3, 3]
                             for b in rec["bricks"]]).reshape(-1, 3))
    return out


def _sample_jpegs() -> list[bytes]:
    """The sample approach video's frames as JPEG (quality 92), as a network camera sends."""
    cap = cv2.VideoCapture(str(APPROACH / "approach.mp4"))
    jpegs = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        jpegs.append(cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 92])[1].tobytes())
    cap.release()
    return jpegs


def _run_command(camera_url: str, port: int, send_held: bool,
                 extra_sinks: tuple[str, ...]) -> list[str]:
    """``drovisio run`` on the camera, its MAVLink sink to ``port`` on loopback."""
    cmd = [sys.executable, "-m", "drovisio", "run", "--source", camera_url,
           "--camera", str(SAMPLE / "camera.yaml"), "--mount", str(APPROACH / "mount.json"),
           *[x for lay in LAYOUTS for x in ("--layout", str(lay))],
           "--sink", f"mavlink:udpout:127.0.0.1:{port}", "--quiet"]
    if send_held:
        cmd.append("--send-held-targets")
    for extra in extra_sinks:
        cmd += ["--sink", extra]
    return cmd


@dataclass
class _WireMatches:
    """Each LANDING_TARGET matched to the frame it describes."""

    latency_ms: list[float] = field(default_factory=list)
    """Last byte of the frame sent → message received, ms."""
    stamp_gaps: list[float] = field(default_factory=list)
    """Message's stamp − the frame's send time, s."""
    stale: int = 0
    stale_gaps_ms: list[float] = field(default_factory=list)
    one_off: int = 0


def _match_messages(got: list[tuple[float, Any]], sent: list[tuple[int, float]],
                    truth: list[np.ndarray], fps: float) -> _WireMatches:
    """Match each message (after the warm-up) to the sent frame whose true body-frame brick
    positions its x, y, z fit best."""
    warm = 3.0                                   # start-up of the process and its kernels
    t_first = sent[0][1] + warm if sent else 0.0
    out = _WireMatches()
    for t_rx, m in got:
        if t_rx < t_first:
            continue
        pos = np.array([m.x, m.y, m.z])
        cands = [(i, t) for i, t in sent if t_rx - 0.5 <= t <= t_rx]
        if not cands:
            continue
        err = [float(np.min(np.linalg.norm(truth[i] - pos, axis=1))) for i, _ in cands]
        k = int(np.argmin(err))
        i, t_sent = cands[k]
        out.latency_ms.append((t_rx - t_sent) * 1e3)
        gap = m.time_usec / 1e6 - t_sent
        out.stamp_gaps.append(gap)
        # the stamp is the capture time of the frame the message describes: read a moment
        # after its last byte left the camera; a message more than one and a half frame
        # intervals older than its stamp describes an earlier frame (a held-over target).
        # Exactly one interval off is the match confusing two frames closer than the
        # detector's own error (counted apart)
        if gap > 1.5 / fps or gap < -0.002:
            out.stale += 1
            out.stale_gaps_ms.append(round(gap * 1e3, 1))
        elif gap > 0.5 / fps:
            out.one_off += 1
    return out


def bench_wire(fps: float, seconds: float, send_held: bool = False,
               extra_sinks: tuple[str, ...] = ()) -> dict:
    """Wire-to-message latency of a separate ``drovisio run`` process (see the module doc);
    ``extra_sinks`` run beside the MAVLink one (e.g. a Zenoh sink that cannot connect: the
    flight controller's path must not change)."""
    jpegs = _sample_jpegs()
    truth = _body_truth()
    mavutil = mavutil2()
    rx = mavutil.mavlink_connection("udpin:127.0.0.1:0")
    port = rx.port.getsockname()[1]
    got: list[tuple[float, Any]] = []
    stop = threading.Event()

    def listen() -> None:
        while not stop.is_set():
            m = rx.recv_match(type="LANDING_TARGET", blocking=True, timeout=0.1)
            if m is not None:
                got.append((time.time(), m))

    th = threading.Thread(target=listen, daemon=True)
    th.start()
    # every third frame: consecutive frames ≥ 6 mm apart, so that the match of a message to
    # its frame is not confused by the detector's own error; a frame recurs only 1.7 s later
    cam = MjpegCamera(jpegs, fps, order=list(range(0, len(jpegs), 3)))
    proc = subprocess.Popen(_run_command(cam.url, port, send_held, extra_sinks),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL)
    try:
        time.sleep(seconds)
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        cam.close()
        stop.set()
        join_thread(th, "listening for LANDING_TARGET")   # each read waits 0.1 s at most
        rx.close()
    sent = cam.sent
    w = _match_messages(got, sent, truth, fps)
    lat_a = np.array(w.latency_ms)
    gaps_ms = np.array(w.stamp_gaps) * 1e3
    return {
        "fps": fps, "seconds": seconds, "frames_sent": len(sent), "messages": len(lat_a),
        "send_held": send_held,
        "wire_to_message_ms": {"median": round(_pct(lat_a, 50), 2),
                               "p90": round(_pct(lat_a, 90), 2),
                               "max": round(float(lat_a.max()) if len(lat_a) else float("nan"),
                                            2)},
        "stale_messages": w.stale,
        "stale_stamp_minus_sent_ms": w.stale_gaps_ms[:20],
        "one_frame_off_matches": w.one_off,
        "stamp_minus_sent_ms": {"median": round(_pct(gaps_ms, 50), 2),
                                "p90": round(_pct(gaps_ms, 90), 2)},
        "run_stderr_tail": proc.stderr.read().decode(errors="replace")[-300:]
        if proc.stderr else "",
        "pass": bool(len(lat_a) and _pct(lat_a, 90) <= 50.0),
    }


def bench_memory(fps: float, minutes: float, warmup_minutes: float, progress: bool) -> dict:
    frames_total = int(round(minutes * 60 * fps))
    samples: list[tuple[float, float]] = []  # (stream minutes, RSS MB)
    every = int(round(fps))  # one sample per stream second
    p = _pipeline(["jsonl:/dev/null", "udp://127.0.0.1:9",
                   "mavlink:udpout:127.0.0.1:9", "ws://127.0.0.1:0"], fps, "max")
    t0 = time.monotonic()
    count = [0]

    def on_frame(frame, out) -> None:
        if frame is None:
            return
        count[0] += 1
        if count[0] % every == 0:
            samples.append((count[0] / fps / 60, rss_mb()))
            if progress and count[0] % (every * 60) == 0:
                print(f"  {count[0] / fps / 60:5.1f} stream min, {samples[-1][1]:.2f} MB, "
                      f"{time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)

    p.add_listener(on_frame)
    gc.collect()
    n = p.run(max_frames=frames_total)
    wall = time.monotonic() - t0
    st = p.snapshot()
    p.close()
    a = np.array(samples)
    post = a[a[:, 0] >= warmup_minutes]
    first = post[post[:, 0] < warmup_minutes + 1.0][:, 1]
    last = post[post[:, 0] >= post[-1, 0] - 1.0][:, 1]
    growth = float(np.median(last) - np.median(first))
    slope = float(np.polyfit(post[:, 0], post[:, 1], 1)[0]) if len(post) > 2 else float("nan")
    return {
        "stream_minutes": minutes, "fps": fps, "frames": n, "wall_seconds": round(wall, 1),
        "acceleration": round(minutes * 60 / wall, 2),
        "warmup_minutes": warmup_minutes,
        "rss_mb": {"start": round(float(a[0, 1]), 2),
                   "after_warmup_median": round(float(np.median(first)), 2),
                   "end_median": round(float(np.median(last)), 2),
                   "max": round(float(a[:, 1].max()), 2)},
        "growth_mb": round(growth, 3), "slope_mb_per_hour": round(slope * 60, 3),
        "detector_errors": st.detector_errors, "pass": bool(growth <= 1.0),
    }


def main(argv: list[str]) -> int:
    ap = ArgumentParser(
        prog="drovisio bench pipeline",
        description="Latency capture → sent at 30 fps, and resident memory over a long run, "
                    "of the drovisio run pipeline on the sample approach video.",
        epilog="Example:\n  drovisio bench pipeline latency --seconds 20\n"
               "  drovisio bench pipeline memory --minutes 20",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", nargs="?", choices=("latency", "wire", "memory", "all"),
                    default="all")
    ap.add_argument("--send-held-targets", action="store_true",
                    help="wire: run drovisio with --send-held-targets (to compare)")
    ap.add_argument("--extra-sink", action="append", default=[], metavar="SINK",
                    help="wire: another sink beside the MAVLink one (to compare), e.g. "
                         "zenoh:connect=tcp/127.0.0.1:9 (a station that is not there)")
    ap.add_argument("--fps", type=number(0, 1000, above=True), default=30.0, help="camera frame rate (default 30)")
    ap.add_argument("--seconds", type=number(0, 86400, above=True), default=20.0, help="latency run length (s)")
    ap.add_argument("--minutes", type=number(0, 1440, above=True), default=20.0,
                    help="memory run length in stream minutes (default 20)")
    ap.add_argument("--warmup-minutes", type=number(0, 1440), default=2.0)
    ap.add_argument("--json", metavar="FILE", help="also write the results here")
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args(argv)
    res: dict = {"machine": {"cpus": os.cpu_count(),
                             "load_1min": round(os.getloadavg()[0], 2)}}
    ok = True
    if a.what in ("latency", "all"):
        r = bench_latency(a.fps, a.seconds)
        res["latency"] = r
        ok &= r["pass"]
        print(f"latency at {a.fps:g} fps: capture → sent median {r['latency_ms']['median']} ms "
              f"(p90 {r['latency_ms']['p90']}, max {r['latency_ms']['max']}; budget "
              f"{r['budget_ms']} ms) — {'PASS' if r['pass'] else 'FAIL'}; capture → received "
              f"by the MAVLink listener median {r['capture_to_received_ms']['median']} ms; "
              f"detect median {r['detect_ms_median']} ms; processed {r['processed_fps']} fps, "
              f"{r['frames_dropped']} of {r['frames_offered']} frames skipped")
    if a.what in ("wire", "all"):
        r = bench_wire(a.fps, a.seconds, a.send_held_targets, tuple(a.extra_sink))
        res["wire"] = r
        ok &= r["pass"]
        w = r["wire_to_message_ms"]
        print(f"wire to message at {a.fps:g} fps (MJPEG camera → drovisio run → MAVLink "
              f"listener, {r['messages']} messages): median {w['median']} ms, p90 {w['p90']} "
              f"ms, max {w['max']} ms — {'PASS' if r['pass'] else 'FAIL'} (p90 ≤ 50 ms); "
              f"{r['stale_messages']} messages describe a frame older than their stamp "
              f"({r['one_frame_off_matches']} matched one frame off: frames closer than the "
              "detector's error)")
    if a.what in ("memory", "all"):
        r = bench_memory(a.fps, a.minutes, a.warmup_minutes, progress=not a.quiet)
        res["memory"] = r
        ok &= r["pass"]
        print(f"memory over {a.minutes:g} stream minutes ({r['frames']} frames at {a.fps:g} fps, "
              f"run accelerated ×{r['acceleration']} in {r['wall_seconds']} s): RSS "
              f"{r['rss_mb']['after_warmup_median']} MB after warm-up → "
              f"{r['rss_mb']['end_median']} MB at the end, growth {r['growth_mb']} MB "
              f"(slope {r['slope_mb_per_hour']} MB/h) — {'PASS' if r['pass'] else 'FAIL'}")
    if a.json:
        atomic_write_text(a.json, json.dumps(res, indent=1))
    return 0 if ok else 1
