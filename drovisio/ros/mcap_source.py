"""``--source FILE.mcap``: replay an MCAP recording's images through the pipeline.

Reads the ``sensor_msgs/msg/CompressedImage`` messages of one topic (the first such topic,
or ``topic``) in file order, with their header stamps as the media clock (so a replay is
paced and tracked with the recorded timing). The file is read as a stream, record after
record, never whole: a recording cut by ``kill -9`` (no summary, a last chunk half written)
plays up to its last complete chunk and then ends; nothing else of a broken file is read.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from drovisio.images import ImageError, decode_image
from drovisio.raw_frame import EndOfStream, RawFrame
from drovisio.ros.msgdefs import decoder

__all__ = ["McapReader", "iter_images"]

IMAGE_TYPE = "sensor_msgs/msg/CompressedImage"
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Largest record (or decompressed chunk) read, bytes; ours are ~1–3 MB.
MAX_RECORD_BYTES = 256 << 20


def iter_images(path: str | Path, topic: str | None = None
                ) -> Iterator[tuple[str, float, bytes, str]]:
    """``(topic, stamp_s, data, format)`` of the file's compressed images, in file order;
    stops quietly at a cut (truncated) end."""
    from mcap.exceptions import McapError  # deferred: an optional dependency (mcap)
    from mcap.records import Channel, Chunk, Message, Schema
    from mcap.stream_reader import StreamReader, breakup_chunk

    dec = decoder(IMAGE_TYPE)
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, int]] = {}
    chosen = topic
    with open(path, "rb") as f:
        # bounded: a damaged or hostile length never allocates more than this
        reader = StreamReader(f, skip_magic=False, emit_chunks=True,
                              record_size_limit=MAX_RECORD_BYTES)
        records = reader.records
        while True:
            try:
                rec = next(records)
            except StopIteration:
                return
            except (McapError, EOFError, ValueError, OSError, Exception):  # noqa: BLE001
                return   # the cut end of a killed recording
            inner = [rec]
            if isinstance(rec, Chunk):
                if rec.uncompressed_size > MAX_RECORD_BYTES:
                    return
                try:
                    inner = list(breakup_chunk(rec, validate_crc=True))
                except Exception:  # noqa: BLE001 - a damaged chunk ends the replay
                    return
            for r in inner:
                if isinstance(r, Schema):
                    schemas[r.id] = r.name
                elif isinstance(r, Channel):
                    channels[r.id] = (r.topic, r.schema_id)
                elif isinstance(r, Message):
                    ch = channels.get(r.channel_id)
                    if ch is None or schemas.get(ch[1]) not in (IMAGE_TYPE,
                                                                "sensor_msgs/CompressedImage"):
                        continue
                    if chosen is None:
                        chosen = ch[0]
                    if ch[0] != chosen:
                        continue
                    m = dec(r.data)
                    t = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
                    yield ch[0], t, bytes(m.data), str(m.format)


class McapReader:
    """A frame reader (:class:`drovisio.sources.Reader`) of an MCAP recording."""

    finite = True
    lossless = False

    def __init__(self, path: str | Path, loop: bool = False, topic: str | None = None):
        self.path = Path(path)
        self.label = f"recording {path}"
        self.loop = loop
        self.finite = not loop
        self.topic = topic
        self._it: Iterator | None = None
        self._t0: float | None = None
        self._offset = 0.0
        self._last = 0.0
        self.index = 0

    def open(self) -> None:
        with open(self.path, "rb") as f:
            magic = f.read(8)
        if magic != MCAP_MAGIC:
            raise OSError("not an MCAP file (it does not begin with MCAP's magic bytes): give "
                          "a recording written by drovisio run --record FILE.mcap or ros2 bag")
        self._it = iter_images(self.path, self.topic)
        self._t0 = None
        self._offset = 0.0
        self.index = 0
        try:
            first = next(self._it)
        except StopIteration:
            raise OSError("the recording holds no complete image "
                          "(sensor_msgs/msg/CompressedImage) to replay") from None
        self._pending: tuple | None = first

    def read(self) -> RawFrame | None:
        assert self._it is not None
        item = self._pending
        self._pending = None
        if item is None:
            item = next(self._it, None)
        if item is None:
            if not self.loop:
                raise EndOfStream()
            self._offset = self._last + 0.1
            self._it = iter_images(self.path, self.topic)
            self._t0 = None
            item = next(self._it, None)
            if item is None:
                raise EndOfStream()
        _topic, t, data, _fmt = item
        if self._t0 is None:
            self._t0 = t
        media = t - self._t0 + self._offset
        self._last = media
        i = self.index
        self.index += 1
        try:   # the project's one decoder: the size bounded from the header, quiet
            img, notes = decode_image(data)
        except ImageError as e:
            return RawFrame(None, i, media_time=media, name=f"{self.path.name}#{i}",
                            error=f"image could not be decoded: {e}")
        return RawFrame(img, i, media_time=media, name=f"{self.path.name}#{i}", notes=notes)

    def close(self) -> None:
        self._it = None
