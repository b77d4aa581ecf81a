"""``drovisio bench fleet``: one ground station and several drones over Zenoh, for minutes.

Measures what a site with several drones needs from the link (loopback, this machine):

* **memory**: the resident size of the station and of every drone process, after a warm-up
  and at the end; the growth between the two (a station that runs all day must not grow);
* **latency**: drone → station, from the frame's capture stamp (``t`` of its JSON output)
  to its arrival in the station's fleet state; median, p90, max;
* **loss**: frames a drone sent that the station never received while the link was up
  (frame numbers are consecutive), and frames the drone's sink dropped itself.

The drones are simulated (three tracked bricks with their covariance per frame, at
``--fps``): the detector's own cost is :mod:`drovisio.bench.pipeline`'s subject, not this
one's. Each drone is a process of its own (``python -m drovisio.bench.fleet --as-drone``), a
real ``ZenohSink`` as ``drovisio run --sink zenoh:`` makes it.

Example::

    drovisio bench fleet --drones 4 --fps 30 --minutes 10 --json fleet.json
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from drovisio.bench.pipeline import rss_mb
from drovisio.bounds import ArgumentParser, number, whole
from drovisio.fileio import atomic_write_text
from drovisio.pipeline import FrameOutput
from drovisio.ros.messages import RosMessages, namespace_for
from drovisio.sinks.zenoh import ZenohSink
from drovisio.station import Fleet, StationLink
from drovisio.tracking import TrackedBrick

__all__ = ["main"]

_RSS_EVERY_S = 5.0


def _free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = int(s.getsockname()[1])
    s.close()
    return port


def _bricks(t: float, k: int) -> list[TrackedBrick]:
    """Three bricks drifting slowly in front of the camera, as a tracker gives them."""
    out = []
    for i in range(3):
        x = 0.2 * (i - 1) + 0.01 * np.sin(0.05 * k + i)
        out.append(TrackedBrick(
            layout="drick-aruco-centre", instance=i, track=i + 1, method="aruco",
            rvec=np.array([0.0, 0.0, 0.1 * i]), tvec=np.array([x, 0.05, 1.2]),
            covariance=np.diag([1e-4, 1e-4, 1e-4, 4e-6, 4e-6, 1e-5]), t=t, t_measured=t,
            age=0.0, measured=True))
    return out


def _drone(drone_id: str, port: int, fps: float, seconds: float) -> dict[str, Any]:
    """One simulated drone: sends ``fps`` frames a second for ``seconds``; returns its
    figures (printed as JSON by ``--as-drone``)."""
    ns, prefix = namespace_for(drone_id)
    sink = ZenohSink(f"zenoh:connect=tcp/127.0.0.1:{port}",
                     RosMessages(None, None, (), namespace=ns, frame_prefix=prefix))
    rss: list[tuple[float, float]] = []
    t0 = time.monotonic()
    k = 0
    next_rss = t0
    try:
        while (now := time.monotonic()) - t0 < seconds:
            t = time.time()
            sink.send(FrameOutput(source="sim", frame=k, seq=k, t=t, t_mono=now,
                                  bricks=(b := _bricks(t, k)), target=b[1]))
            k += 1
            if now >= next_rss:
                rss.append((now - t0, rss_mb()))
                next_rss += _RSS_EVERY_S
            time.sleep(max(0.0, t0 + k / fps - time.monotonic()))
        time.sleep(0.5)   # let the last frames leave
        st = sink.status()
    finally:
        sink.close()
    return {"drone": drone_id, "frames": k, "sent": st["sent"], "dropped": st["dropped"],
            "errors": st["errors"], "rss": rss}


class _Measuring(Fleet):
    """The station's fleet state, also keeping every frame's latency and the gaps in each
    drone's frame numbers (preallocated: the measurement must not grow the station)."""

    def __init__(self, capacity: int):
        super().__init__()
        self.latency_ms = np.full(capacity, np.nan)
        self.n = 0
        self.received: dict[str, int] = {}
        self.missing: dict[str, int] = {}
        self._last: dict[str, int] = {}
        self._m = threading.Lock()
        self.measuring = False

    def frame(self, drone_id: str, output: dict[str, Any], t_recv: float | None = None,
              mono: float | None = None) -> None:
        t_recv = time.time() if t_recv is None else t_recv
        super().frame(drone_id, output, t_recv, mono)
        with self._m:
            self.received[drone_id] = self.received.get(drone_id, 0) + 1
            f = output.get("frame")
            last = self._last.get(drone_id)
            if isinstance(f, int) and last is not None and f > last + 1:
                self.missing[drone_id] = self.missing.get(drone_id, 0) + f - last - 1
            if isinstance(f, int):
                self._last[drone_id] = f
            if self.measuring and self.n < self.latency_ms.size:
                self.latency_ms[self.n] = 1000.0 * (t_recv - float(output["t"]))
                self.n += 1


def _growth(rss: list[tuple[float, float]], warmup_s: float) -> dict[str, float | None]:
    """Resident size after the warm-up and at the end (medians of three samples), MB."""
    after = [m for t, m in rss if t >= warmup_s]
    if len(after) < 2:
        return {"after_warmup_mb": None, "end_mb": None, "growth_mb": None}
    a, b = float(np.median(after[:3])), float(np.median(after[-3:]))
    return {"after_warmup_mb": round(a, 2), "end_mb": round(b, 2), "growth_mb": round(b - a, 2)}


def run_fleet(drones: int, fps: float, seconds: float, warmup_s: float,
              progress: bool = True) -> dict[str, Any]:
    """Run the station here and ``drones`` drone processes; return the figures."""
    port = _free_port()
    fleet = _Measuring(capacity=int(drones * fps * seconds * 1.1) + 100)
    link = StationLink(fleet, listen=[f"tcp/127.0.0.1:{port}"])
    ids = [f"drone{k + 1}" for k in range(drones)]
    procs = [subprocess.Popen([sys.executable, "-m", "drovisio.bench.fleet", "--as-drone", i,
                               "--port", str(port), "--fps", str(fps),
                               "--seconds", str(seconds)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i in ids]
    station_rss: list[tuple[float, float]] = []
    t0 = time.monotonic()
    try:
        while any(p.poll() is None for p in procs):
            el = time.monotonic() - t0
            fleet.measuring = el >= warmup_s
            station_rss.append((el, rss_mb()))
            if progress:
                live = sum(d.state == "live" for d in fleet.status())
                print(f"\r{el:6.0f} s of {seconds:.0f}: {live}/{drones} drones live, "
                      f"{sum(fleet.received.values())} frames", end="", file=sys.stderr,
                      flush=True)
            time.sleep(min(_RSS_EVERY_S, 1.0))
        if progress:
            print(file=sys.stderr)
        results = []
        for p, i in zip(procs, ids):
            out, err = p.communicate(timeout=30)
            if p.returncode != 0:
                raise RuntimeError(f"drone {i} failed: {err.strip().splitlines()[-1:]}")
            results.append(json.loads(out.strip().splitlines()[-1]))
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
        link.close()
    lat = fleet.latency_ms[:fleet.n]
    rss_station = [(t, m) for t, m in station_rss]
    return {
        "drones": drones, "fps": fps, "seconds": seconds, "warmup_s": warmup_s,
        "latency_ms": {"frames": int(lat.size),
                       "median": round(float(np.median(lat)), 2) if lat.size else None,
                       "p90": round(float(np.percentile(lat, 90)), 2) if lat.size else None,
                       "max": round(float(lat.max()), 2) if lat.size else None},
        "station": {"received": sum(fleet.received.values()),
                    "missing": sum(fleet.missing.values()), "dropped_bad": link.dropped,
                    **_growth(rss_station, warmup_s)},
        "per_drone": [{"drone": r["drone"], "sent": r["sent"], "dropped_in_sink": r["dropped"],
                       "received": fleet.received.get(r["drone"], 0),
                       "missing": fleet.missing.get(r["drone"], 0),
                       **_growth([(float(t), float(m)) for t, m in r["rss"]], warmup_s)}
                      for r in results],
    }


def _report(r: dict[str, Any]) -> str:
    lat = r["latency_ms"]
    lines = [f"fleet: 1 station, {r['drones']} drones at {r['fps']:g} fps for "
             f"{r['seconds'] / 60:.1f} min (after a {r['warmup_s']:.0f} s warm-up):",
             f"  latency capture → station: median {lat['median']} ms, p90 {lat['p90']} ms, "
             f"max {lat['max']} ms over {lat['frames']} frames",
             f"  station: {r['station']['received']} frames received, "
             f"{r['station']['missing']} missing; memory {r['station']['after_warmup_mb']} → "
             f"{r['station']['end_mb']} MB (growth {r['station']['growth_mb']} MB)"]
    for d in r["per_drone"]:
        lines.append(f"  {d['drone']}: sent {d['sent']}, received {d['received']}, "
                     f"missing {d['missing']}, dropped in its sink {d['dropped_in_sink']}; "
                     f"memory {d['after_warmup_mb']} → {d['end_mb']} MB "
                     f"(growth {d['growth_mb']} MB)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(
        prog="drovisio bench fleet",
        description="One ground station and several simulated drones over Zenoh (loopback): "
                    "memory growth of every process, latency capture → station, frames lost.",
        epilog="Example:\n  drovisio bench fleet --drones 4 --fps 30 --minutes 10")
    ap.add_argument("--drones", type=whole(1, 16), default=4,
                    help="simulated drones (default 4)")
    ap.add_argument("--fps", type=number(1, 120), default=30.0, help="frames a second each")
    ap.add_argument("--minutes", type=number(0.05, 600), default=10.0,
                    help="length of the run (default 10)")
    ap.add_argument("--warmup-minutes", type=number(0, 60), default=1.0,
                    help="left out of the memory and latency figures (default 1)")
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    ap.add_argument("--quiet", action="store_true", help="no progress line")
    ap.add_argument("--as-drone", metavar="ID", help=argparse.SUPPRESS)
    ap.add_argument("--port", type=whole(1, 65535), help=argparse.SUPPRESS)
    ap.add_argument("--seconds", type=number(0.1, 36000), help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.as_drone:
        print(json.dumps(_drone(a.as_drone, int(a.port), float(a.fps), float(a.seconds))))
        return 0
    seconds = 60.0 * float(a.minutes)
    warmup = min(60.0 * float(a.warmup_minutes), seconds / 2)
    r = run_fleet(int(a.drones), float(a.fps), seconds, warmup, progress=not a.quiet)
    print(_report(r))
    if a.json:
        atomic_write_text(Path(a.json), json.dumps(r, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
