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


def test_source_fails_mid_stream_and_comes_back(flaky_reader, fake_detector, monkeypatch, until):
    reader = flaky_reader(fps=30)
    src = FrameSource(reader, backoff=(0.05, 0.2))
    pauses: list[float] = []           # the reader thread's pauses between reopen attempts
    pause = src._sleep
    monkeypatch.setattr(src, "_sleep", lambda s: (pauses.append(s), pause(s)))
    sink = ListSink()
    p = Pipeline(src, [fake_detector()], sinks=[sink, BrokenSink()], max_age=0.5)
    states: list[SourceState] = []
    p.add_listener(lambda f, o: states.append(src.state))
    # (time of each idle tick's pruning, tracks left): prune's own time, so no race
    prunes: list[tuple[float, int]] = []
    prune = p.tracker.prune

    def recording_prune(t):
        prune(t)
        prunes.append((t, len(p.tracker.tracks)))

    monkeypatch.setattr(p.tracker, "prune", recording_prune)

    def poses(items):
        return [o for _, o in items if o.bricks]

    th = threading.Thread(target=p.run, daemon=True)
    th.start()
    try:
        until(lambda: len(poses(sink.items)) > 10)                  # poses flow ...
        reader.unplug()
        until(lambda: src.state == SourceState.LOST)
        k = len(prunes)
        # ... the tracks are gone without frames (idle ticks age them out) ...
        until(lambda: any(n == 0 for _, n in prunes[k:]))
        lost, k = len(sink.items), len(prunes)
        reader.plug()
        # ... and poses resume once the source is back
        until(lambda: poses(sink.items[lost:]) and src.state == SourceState.LIVE)
    finally:
        p.stop()
        th.join(60)
        p.close()
    assert not th.is_alive()
    # no track outlived max_age without a measurement: every idle tick of the loss later
    # than that after the last pose left none
    last = max(o.t_mono for o in poses(sink.items[:lost]))
    assert all(n == 0 for t, n in prunes[:k] if t > last + 0.5)
    assert SourceState.LOST in states and states[-1] == SourceState.LIVE
    assert src.reconnects >= 1 and reader.opens >= 2
    # reopened after pauses growing from 0.05 s to at most 0.2 s
    assert pauses and pauses[0] == 0.05 and max(pauses) <= 0.2
    # every pose carries its capture time and age, none older than max_age
    for _, o in sink.items:
        for b in o.bricks:
            assert b.t == o.t and 0 <= b.age <= 0.5
    assert p.stats.sink_errors == len(sink.items)  # the broken sink never stopped anything


class WaitsForFrames:
    """A detector slower than the camera: each detection lasts until the reader has read
    five more frames (counted, not timed), then finds nothing."""

    name = "slow"

    def __init__(self, reader, until):
        self.reader = reader
        self.until = until
        self.read_by_end: list[int] = []   # frames read when each detection ended

    def detect(self, image, gravity=None):
        start = self.reader.i
        self.until(lambda: self.reader.i >= start + 5)
        self.read_by_end.append(self.reader.i)
        return []


def test_newest_frame_with_slow_detector(flaky_reader, until):
    reader = flaky_reader(fps=60)
    src = FrameSource(reader)
    sink = ListSink()
    det = WaitsForFrames(reader, until)
    p = Pipeline(src, [det], sinks=[sink])
    th = threading.Thread(target=p.run, daemon=True)
    th.start()
    try:
        until(lambda: len(sink.items) >= 6)
    finally:
        p.stop()
        th.join(60)
        p.close()
    frames = [o.frame for _, o in sink.items]
    # after each detection the next one takes the newest frame: when a detection ended with
    # N frames read, frame N-2 was already handed over (N-1 may still be on its way); a queue
    # would give the oldest waiting one (the previous frame + 1) instead
    for k in range(1, len(frames)):
        assert frames[k] >= det.read_by_end[k - 1] - 2, (frames, det.read_by_end)
    # the frames the detector had no time for were skipped, counted as dropped
    assert src.dropped >= sum(b - a - 1 for a, b in zip(frames, frames[1:], strict=False))
    assert src.dropped >= 3 * (len(frames) - 1)


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
