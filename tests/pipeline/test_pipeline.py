"""The pipeline with a fake detector: newest frame, loss and recovery, errors, recording."""

from __future__ import annotations

import json
import threading
import time

import numpy as np

from drovisio.pipeline import Pipeline
from drovisio.recording import Recorder, read_index
from drovisio.sources import FrameSource, RecordingReader, SourceState


class ListSink:
    name = "list"

    def __init__(self):
        self.items = []

    def send(self, out):
        self.items.append((time.monotonic(), out))

    def close(self):
        pass

    def status(self):
        return {"sink": self.name, "sent": len(self.items)}


class BrokenSink(ListSink):
    name = "broken"

    def send(self, out):
        raise OSError("network unreachable")


def _run_for(p: Pipeline, seconds: float) -> threading.Thread:
    th = threading.Thread(target=p.run, daemon=True)
    th.start()
    time.sleep(seconds)
    p.stop()
    th.join(5)
    assert not th.is_alive()
    return th


def test_source_fails_mid_stream_and_comes_back(flaky_reader, fake_detector):
    reader = flaky_reader(fps=30, fail_at=0.8, back_at=1.6)
    src = FrameSource(reader, backoff=(0.05, 0.2))
    sink = ListSink()
    p = Pipeline(src, [fake_detector()], sinks=[sink, BrokenSink()], max_age=0.5)
    states, idle = [], []
    p.add_listener(lambda f, o: states.append((time.monotonic(), src.state)))
    p.add_listener(lambda f, o: idle.append((time.monotonic(), len(p.tracker.tracks)))
                   if f is None else None)
    t_start = time.monotonic()
    _run_for(p, 2.6)
    p.close()
    t0 = reader.t0
    assert t0 is not None and t0 - t_start < 0.2
    with_bricks = [t for t, o in sink.items if o.bricks]
    before = [t for t in with_bricks if t < t0 + 0.8]
    after = [t for t in with_bricks if t > t0 + 1.6]
    assert len(before) > 10, "poses flow before the loss"
    # poses stop within 0.5 s of the loss ...
    during = [t for t in with_bricks if t0 + 0.8 + 0.5 < t < t0 + 1.6]
    assert during == []
    # ... the tracks are gone within max_age even without frames ...
    late_idle = [n for t, n in idle if t0 + 0.8 + 0.55 < t < t0 + 1.6]
    assert late_idle and max(late_idle) == 0
    # ... and poses resume after the source is back (backoff ≤ 0.2 s)
    assert after and after[0] < t0 + 1.6 + 0.5
    seen = [s for _, s in states]
    assert SourceState.LOST in seen and seen[-1] == SourceState.LIVE
    assert src.reconnects >= 1
    # every pose carries its capture time and age, none older than max_age
    for _, o in sink.items:
        for b in o.bricks:
            assert b.t == o.t and 0 <= b.age <= 0.5
    assert p.stats.sink_errors == len(sink.items)  # the broken sink never stopped anything


def test_newest_frame_with_slow_detector(flaky_reader, fake_detector):
    reader = flaky_reader(fps=60)
    src = FrameSource(reader)
    sink = ListSink()
    p = Pipeline(src, [fake_detector(delay=0.05)], sinks=[sink])
    _run_for(p, 1.0)
    p.close()
    assert src.dropped > 10  # frames the detector had no time for were skipped ...
    lat = [(t - o.t_mono) for t, o in sink.items]
    assert max(lat) < 0.05 + 1 / 60 + 0.03  # ... so no queue: latency = one detection


def test_detector_errors_do_not_stop_the_pipeline(flaky_reader, fake_detector):
    src = FrameSource(flaky_reader(fps=100, n=30), pace="max")
    sink = ListSink()
    p = Pipeline(src, [fake_detector(raise_every=3), fake_detector()], sinks=[sink])
    n = p.run()
    p.close()
    assert n == 30 and len(sink.items) == 30
    assert p.stats.detector_errors == 10
    assert any("boom" in "; ".join(o.errors) for _, o in sink.items)
    assert src.state == SourceState.ENDED


def test_tracker_smooths_and_outputs_json(flaky_reader, fake_detector):
    src = FrameSource(flaky_reader(fps=200, n=60), pace="max")
    sink = ListSink()
    p = Pipeline(src, [fake_detector(noise=0.003, seed=1)], sinks=[sink])
    p.run()
    p.close()
    t = np.array([o.bricks[0].tvec for _, o in sink.items[20:]])
    raw = np.array([o.detections[0].tvec for _, o in sink.items[20:]])
    assert t.std(axis=0).max() < 0.7 * raw.std(axis=0).max()
    js = json.loads(json.dumps(sink.items[-1][1].to_json()))
    b = js["bricks"][0]
    assert js["file"] == "fake camera" and b["layout"] == "drick-aruco-centre"
    assert b["measured"] is True and b["age"] == 0.0 and b["t"] == js["t"]


def test_record_and_play_back(tmp_path, flaky_reader, fake_detector):
    src = FrameSource(flaky_reader(fps=50, n=12, size=(32, 24)), pace="max")
    rec = Recorder(tmp_path / "rec", source="fake")
    p = Pipeline(src, [fake_detector()], sinks=[], recorder=rec)
    p.run()
    p.close()
    idx = read_index(tmp_path / "rec")
    assert [e.frame for e in idx] == list(range(12))
    first = json.loads((tmp_path / "rec" / "frames.jsonl").read_text().splitlines()[0])
    assert first["output"]["bricks"][0]["instance"] == 1
    assert (tmp_path / "rec" / "recording.json").is_file()
    # played back as a source, at the recorded timing
    back = FrameSource(RecordingReader(tmp_path / "rec"), pace="realtime")
    sink = ListSink()
    p2 = Pipeline(back, [fake_detector()], sinks=[sink])
    t0 = time.monotonic()
    p2.run()
    p2.close()
    # a live source hands over its newest frame: a starved machine may skip one, never
    # reorder or repeat, and the recording plays to its end
    got = [o.frame for _, o in sink.items]
    assert got == sorted(set(got)) and got[-1] == 11 and set(got) <= set(range(12))
    span = idx[-1].t - idx[0].t
    assert time.monotonic() - t0 >= 0.8 * span
