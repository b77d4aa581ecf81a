"""Class: video files and stream URLs as sources.

* A video's frame size is read from its container (AVI ``avih``/``strf``, MP4 ``tkhd``) and
  from the decoder before the first frame is decoded, and refused over the image caps in one
  line: ``run`` exits 2, ``detect`` answers one error line for that file.
* A single picture as ``run --source`` that cannot be decoded (or any file none of whose
  frames decodes) cannot be opened: exit 2, one line — not one error frame and exit 0.
* A stream URL gets a connect and a read deadline (OpenCV's open and read timeouts), each
  reported in one line naming the URL and the deadline. Loopback peers only.
"""

from __future__ import annotations

import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio.images import video_header_size
from drovisio.sources import StreamReader, VideoFileReader

REPO = Path(__file__).resolve().parents[2]
CAMERA = REPO / "sample_sessions" / "camera.yaml"
LAYOUT = REPO / "marker_layouts" / "drick-aruco-centre.json"


def _drovisio(*argv: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "drovisio", *argv], capture_output=True,
                          text=True, timeout=timeout, cwd=REPO)


def _one_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err and "internal error" not in err.lower()
    return lines[0]


def _write_video(path: Path, fourcc: str, n: int = 5, size=(64, 48)) -> Path:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 10, size)
    assert w.isOpened()
    for i in range(n):
        w.write(np.full((size[1], size[0], 3), 40 * i, np.uint8))
    w.release()
    return path


@pytest.fixture
def small_avi(tmp_path) -> Path:
    return _write_video(tmp_path / "small.avi", "MJPG")


@pytest.fixture
def huge_avi(small_avi, tmp_path) -> Path:
    """A 5-frame MJPEG AVI whose headers announce 30000x30000 frames (900 Mpx)."""
    d = bytearray(small_avi.read_bytes())
    i = d.find(b"avih")
    struct.pack_into("<II", d, i + 8 + 32, 30000, 30000)
    j = d.find(b"strf")
    struct.pack_into("<ii", d, j + 8 + 4, 30000, 30000)
    p = tmp_path / "huge.avi"
    p.write_bytes(bytes(d))
    return p


def test_container_sizes_are_read_without_decoding(small_avi, huge_avi, tmp_path, ledger):
    ledger.tried["videos: header size"] += 4
    assert video_header_size(small_avi) == (64, 48)
    assert video_header_size(huge_avi) == (30000, 30000)
    mp4 = _write_video(tmp_path / "small.mp4", "mp4v", size=(80, 60))
    assert video_header_size(mp4) == (80, 60)
    # an MP4 whose track header lies: 40000x40000 (16.16 fixed point)
    d = bytearray(mp4.read_bytes())
    k = d.find(b"tkhd")
    version = d[k + 4]
    at = k + 8 + (32 if version == 1 else 20) + 16 + 36
    struct.pack_into(">II", d, at, 40000 << 16, 40000 << 16)
    lying = tmp_path / "lying.mp4"
    lying.write_bytes(bytes(d))
    assert video_header_size(lying) == (40000, 40000)
    with pytest.raises(OSError, match=r"40000x40000 \(1600 Mpx\)"):
        VideoFileReader(lying).open()
    # not a container it knows, or a truncated one: unknown (the decoder's size decides)
    assert video_header_size(tmp_path / "small.avi") is not None
    (tmp_path / "cut.mp4").write_bytes(mp4.read_bytes()[:20])
    assert video_header_size(tmp_path / "cut.mp4") is None


def test_a_huge_video_header_is_refused_in_one_line(huge_avi, ledger):
    ledger.tried["videos: header size"] += 2
    with pytest.raises(OSError) as e:
        VideoFileReader(huge_avi).open()
    assert "30000x30000 (900 Mpx)" in str(e.value) and str(huge_avi) in str(e.value)
    r = _drovisio("run", "--source", str(huge_avi), "--camera", str(CAMERA), "--layout",
                  str(LAYOUT), "--sink", "jsonl:-", "--quiet")
    assert r.returncode == 2
    line = _one_line(r.stderr)
    assert "--source" in line and "30000x30000" in line and "DROVISIO_MAX_IMAGE_MPX" in line
    assert r.stdout == ""


def test_a_good_video_still_plays_every_frame(small_avi):
    rd = VideoFileReader(small_avi)
    rd.open()
    got = []
    try:
        while True:
            f = rd.read()
            got.append((f.index, int(f.image[0, 0, 0]), f.media_time))
    except Exception as e:  # noqa: BLE001 - the end of the video
        assert type(e).__name__ == "EndOfStream"
    rd.close()
    assert [g[0] for g in got] == [0, 1, 2, 3, 4]
    assert [g[2] for g in got] == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4])
    # MJPEG is lossy: the flat grey levels 0, 40, 80, ... come back within a few levels
    assert np.allclose([g[1] for g in got], [0, 40, 80, 120, 160], atol=4)


@pytest.mark.parametrize("content", [b"", b"\xff\xd8\xff\xe0" + b"\x00" * 64,
                                     bytes(range(256)) * 12])
def test_an_undecodable_picture_as_source_is_exit_2(tmp_path, content, ledger):
    ledger.tried_one("videos: undecodable source")
    bad = tmp_path / "shot.jpg"
    bad.write_bytes(content)
    r = _drovisio("run", "--source", str(bad), "--camera", str(CAMERA), "--layout",
                  str(LAYOUT), "--sink", "jsonl:-", "--quiet")
    assert r.returncode == 2, (r.stdout, r.stderr)
    line = _one_line(r.stderr)
    assert f"{bad}: --source:" in line and line.count(str(bad)) == 1
    assert r.stdout == ""  # no error frame was emitted


def test_a_video_none_of_whose_frames_decodes_cannot_be_opened(small_avi, tmp_path, ledger):
    ledger.tried_one("videos: undecodable source")
    d = bytearray(small_avi.read_bytes())
    # zero every frame's payload: the container is intact, no frame decodes
    i = d.find(b"00dc", d.find(b"movi"))
    while i >= 0:
        n = struct.unpack_from("<I", d, i + 4)[0]
        d[i + 8:i + 8 + n] = bytes(n)
        i = d.find(b"00dc", i + 8 + n)
    p = tmp_path / "blank.avi"
    p.write_bytes(bytes(d))
    with pytest.raises(OSError, match="blank.avi: "):
        VideoFileReader(p).open()


# ------------------------------------------------------------------------------------------
# Streams: loopback peers that never answer, or answer and then stall
# ------------------------------------------------------------------------------------------


class _Peer:
    """A loopback TCP server; ``reply`` is sent on each connection, which is then held open
    (silent) until the peer is closed."""

    def __init__(self, reply: bytes = b""):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.port = self.sock.getsockname()[1]
        self.reply = reply
        self.conns: list[socket.socket] = []
        self.stop = threading.Event()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        self.sock.settimeout(0.2)
        while not self.stop.is_set():
            try:
                c, _ = self.sock.accept()
            except OSError:
                continue
            self.conns.append(c)
            try:
                c.recv(4096)
                if self.reply:
                    c.sendall(self.reply)
            except OSError:
                pass

    def close(self):
        self.stop.set()
        for c in self.conns:
            c.close()
        self.sock.close()


def _mjpeg_reply() -> bytes:
    ok, jpg = cv2.imencode(".jpg", np.full((48, 64, 3), 90, np.uint8))
    assert ok
    part = (b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: "
            + str(len(jpg)).encode() + b"\r\n\r\n" + jpg.tobytes() + b"\r\n")
    return (b"HTTP/1.0 200 OK\r\nContent-Type: multipart/x-mixed-replace; boundary=frame"
            b"\r\n\r\n" + part * 3)


def test_a_silent_stream_is_reported_within_its_connect_deadline(ledger):
    ledger.tried_one("network: stream deadline")
    peer = _Peer()
    try:
        url = f"http://127.0.0.1:{peer.port}/cam.mjpg"
        r = StreamReader(url, open_timeout_s=1.0, read_timeout_s=1.0)
        t0 = time.monotonic()
        with pytest.raises(OSError) as e:
            r.open()
        assert time.monotonic() - t0 < 60  # bounded: the deadline, not FFmpeg's default
        msg = str(e.value)
        assert url in msg and "within 1 s" in msg and "\n" not in msg
    finally:
        peer.close()


def test_a_refused_stream_says_how_long_the_attempt_took(monkeypatch, ledger):
    """Refused in 1 s of a 5 s deadline: said as it was, not as 5 s of waiting."""
    ledger.tried_one("network: stream deadline")
    from types import SimpleNamespace

    from drovisio.sources import stream

    clock = iter([100.0, 101.0])
    monkeypatch.setattr(stream, "time", SimpleNamespace(monotonic=lambda: next(clock)))
    r = StreamReader("rtsp://10.0.0.2/cam", open_timeout_s=5.0)
    monkeypatch.setattr(r, "_make", lambda: SimpleNamespace(isOpened=lambda: False,
                                                            release=lambda: None))
    with pytest.raises(OSError) as e:
        r.open()
    assert str(e.value) == ("cannot open rtsp://10.0.0.2/cam: no video stream there (refused, "
                            "or not a video: the attempt ended after 1.0 s, before the 5 s "
                            "deadline); check the address, and that the camera is on and "
                            "streaming")


def test_a_stalled_stream_is_lost_after_its_read_deadline(ledger):
    ledger.tried_one("network: stream deadline")
    peer = _Peer(_mjpeg_reply())
    try:
        url = f"http://127.0.0.1:{peer.port}/cam.mjpg"
        r = StreamReader(url, open_timeout_s=5.0, read_timeout_s=1.0)
        r.open()
        frames = []
        t0 = time.monotonic()
        with pytest.raises(OSError) as e:
            for _ in range(50):
                frames.append(r.read())
        assert time.monotonic() - t0 < 60   # bounded (a bound for failures only)
        r.close()
        # the frames it sent arrive, with their pixels; then the stall is named in one line
        assert 1 <= len(frames) <= 3
        assert abs(int(frames[0].image[20, 30, 1]) - 90) <= 3
        assert url in str(e.value) and "within 1 s" in str(e.value)
    finally:
        peer.close()


@pytest.mark.parametrize("announced", [400_000_000, 4_000_000_000])
def test_a_huge_announced_frame_count_costs_nothing(small_avi, tmp_path, announced, ledger):
    """A header that announces hundreds of millions of frames: the 5 real frames play, then
    one line says where the file ends (a count of 10^9 or more is taken as unknown)."""
    ledger.tried_one("videos: header frame count")
    d = bytearray(small_avi.read_bytes())
    i = d.find(b"avih")
    struct.pack_into("<I", d, i + 8 + 16, announced)      # dwTotalFrames
    j = d.find(b"strh")
    struct.pack_into("<I", d, j + 8 + 32, announced)      # the video stream's dwLength
    p = tmp_path / "many.avi"
    p.write_bytes(bytes(d))
    rd = VideoFileReader(p)
    rd.open()
    got = []
    with pytest.raises(Exception) as end:  # noqa: PT011 - EndOfStream, after the frames
        for _ in range(50):  # bounded: a reader that believed the header would go on
            f = rd.read()
            got.append((f.index, f.error))
    rd.close()
    assert type(end.value).__name__ == "EndOfStream"
    assert [g[0] for g in got[:5]] == [0, 1, 2, 3, 4] and all(g[1] is None for g in got[:5])
    if announced < 10**9:
        assert len(got) == 6 and f"{announced - 5} frames before" in got[5][1]
    else:
        assert len(got) == 5


@pytest.mark.parametrize("url", ["http://", "rtsp:///stream", "http://[::1", "http://[::1]:x/",
                                 "tcp://127.0.0.1:99999", "https://h:-1/"])
@pytest.mark.parametrize("command", ["run", "serve"])
def test_a_stream_url_that_can_never_connect_is_refused_at_start_up(cli, hostile_files, url,
                                                                    command):
    f = hostile_files
    argv = [command, "--source", url, "--camera", str(f["camera"]), "--layout",
            str(f["layout"])]
    argv += (["--sink", "jsonl:-", "--quiet"] if command == "run"
             else ["--port", str(f["busy_port"])])
    rc, out, err = cli(*argv, cls="network: stream URLs", seconds=180)
    assert rc == 2, err[-300:]
    line = err.strip().splitlines()[-1]
    assert f"{url}: --source:" in line and "cannot listen" not in err
    assert "Traceback" not in err and "internal error" not in err


def test_a_sound_stream_url_is_left_to_reconnect():
    from drovisio.sources import reader_for

    for url in ("rtsp://cam.local:554/live", "udp://@:5000", "http://127.0.0.1:8080/v.mjpg",
                "srt://10.0.0.2:9000"):
        assert isinstance(reader_for(url), StreamReader), url
