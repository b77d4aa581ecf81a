"""Frame sources: camera, video file, folder of images, stream URL, recording, sample
playback — the one way Drovisio reads frames (the pipeline, the web tool's pages, the command
line and the benchmarks all use these readers).

A source is a :class:`Reader` (opens, reads one frame, closes; knows nothing about threads)
wrapped in a :class:`FrameSource`, which reads in its own thread and keeps **only the newest
frame**: a slow detector never makes a queue grow behind it; frames it had no time for are
counted as dropped. On loss (camera unplugged, stream down, read error) the thread closes
the reader and reopens it with a growing pause (0.1 s doubling to 2 s), reports the state
(:class:`SourceState`) and the last error, and never raises.

Timestamps: each :class:`Frame` carries its capture time twice, ``t_mono``
(``time.monotonic()``, for ages and latencies) and ``t_wall`` (UNIX time, for outputs), taken
when the reader returned the frame. Files and recordings are *played* like a camera
(``pace="realtime"``: at their own frame rate, dropping frames when the consumer is slow) or
as fast as the consumer takes them without dropping any (``pace="max"``).

A V4L2 camera is opened once per process (:class:`SharedCamera`) and shared by all its
readers, so that the web tool's calibration page and live view can watch the same camera.

A frame that cannot be decoded (a damaged frame of a video, an unreadable image in a folder)
is not a loss of the source: the reader returns a :class:`RawFrame` carrying ``error``, the
batch iteration of the command line (:func:`iter_inputs`) turns it into an ``"error"`` line, and
:class:`FrameSource` hands it over too (the pipeline reports it). A *finite* source (file,
folder, recording) that cannot be opened, or whose reader fails while reading, is not
retried: it ends in :attr:`SourceState.FAILED` with the reason; cameras and stream URLs keep
reconnecting and say so in their state.

SOURCE strings (:func:`reader_for`, the ``--source`` of ``drovisio run``): a camera index
(``0``: V4L2), a video file, a folder of images (name order), a recording folder (made by
``--record``; has ``recording.json``), or a stream URL (``rtsp://``, ``http://``, ``udp://``,
``tcp://`` …, through FFmpeg).

Modules: :mod:`~drovisio.sources.reader` (the :class:`Reader` protocol),
:mod:`~drovisio.sources.frame_source` (the threaded :class:`FrameSource` and its reconnect
loop), one per kind of reader (:mod:`~drovisio.sources.camera`,
:mod:`~drovisio.sources.video`, :mod:`~drovisio.sources.folders`,
:mod:`~drovisio.sources.stream`, :mod:`~drovisio.sources.playback`; MCAP recordings:
:mod:`drovisio.ros.mcap_source`), :mod:`~drovisio.sources.source_string` (SOURCE strings to
readers) and :mod:`~drovisio.sources.batch` (the command line's inputs).
"""

from drovisio.raw_frame import EndOfStream, RawFrame
from drovisio.sources.batch import FrameItem, iter_inputs
from drovisio.sources.camera import CameraReader, SharedCamera, open_v4l2
from drovisio.sources.folders import ImageFolderReader, RecordingReader, list_folder
from drovisio.sources.frame_source import Frame, FrameSource, SourceState, SourceStatus
from drovisio.sources.playback import PlaybackReader
from drovisio.sources.reader import Pace, Reader
from drovisio.sources.source_string import open_source, reader_for
from drovisio.sources.stream import StreamReader
from drovisio.sources.video import MAX_BAD_FRAMES_IN_A_ROW, VideoFileReader

__all__ = [
    "MAX_BAD_FRAMES_IN_A_ROW",
    "CameraReader",
    "EndOfStream",
    "Frame",
    "FrameItem",
    "FrameSource",
    "ImageFolderReader",
    "Pace",
    "PlaybackReader",
    "RawFrame",
    "Reader",
    "RecordingReader",
    "SharedCamera",
    "SourceState",
    "SourceStatus",
    "StreamReader",
    "VideoFileReader",
    "iter_inputs",
    "list_folder",
    "open_source",
    "open_v4l2",
    "reader_for",
]
