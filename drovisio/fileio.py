"""Writing files so that nothing already saved is lost.

One writer for every file the project writes (camera files, layouts, meshes, reports,
calibration sessions, designer exports): the content goes to a temporary file in the same
folder, is flushed to the disk and **checked** (not empty; the caller's ``verify`` re-reads it,
e.g. a camera file is parsed back and compared), and only then renamed over the target. A
reader, a crash or a full disk sees the old file or the new one, never a part. Failures
raise :class:`~drovisio.errors.WriteError` with one line that names the file and what to do;
the old file is untouched. Permissions: a replaced file keeps its mode, a new one gets the
umask's.
"""

from __future__ import annotations

import errno
import os
import stat
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path

from drovisio.errors import WriteError, one_line

__all__ = ["APPENDED", "FILE", "FOLDER", "MadeFiles", "atomic_write", "atomic_write_bytes", "atomic_write_text",
           "check_output_name", "check_output_path", "check_outputs", "guard_outputs",
           "output_folder", "save_figure", "write_video"]

NAME_MAX = 255
"""Longest file name (bytes) on the file systems a drone or laptop uses (ext4, btrfs, vfat)."""
PATH_MAX = 4096


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _umask()


def _explain(path: Path, e: OSError) -> WriteError:
    if e.errno in (errno.ENOSPC, errno.EDQUOT):
        why = "the disk is full; free some space and try again"
    elif e.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        why = f"not allowed to write there ({e.strerror}); choose another folder"
    elif e.errno == errno.ENOENT:
        why = "the folder does not exist; create it or choose another"
    else:
        why = f"{e.strerror or e}"
    return WriteError(f"{path}: not written: {why} (any previous file is kept)", e.errno or 0)


def check_output_name(path: str | os.PathLike, what: str = "--out") -> Path:
    """Refuse an output name the file system cannot hold (a NUL byte, a control character, a
    name over 255 bytes, a path over 4096) before any work is done: the OS would only say so
    at the end, after the work, as ``Errno 36``.

    Raises:
        WriteError: one line naming the option and what to do.
    """
    text = os.fspath(path)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    shown = one_line(repr(text) if any(ord(ch) < 32 for ch in text) else text, 120)
    if not text:
        raise WriteError(f"{what}: empty name; give a file name", errno.EINVAL)
    if "\x00" in text:
        raise WriteError(f"{shown}: {what}: the name contains a NUL byte; give a real file "
                         "name", errno.EINVAL)
    if any(ord(ch) < 32 or ord(ch) == 127 for ch in text):
        raise WriteError(f"{shown}: {what}: the name contains a control character (a line "
                         "break, a tab); give a plain file name", errno.EINVAL)
    try:
        parts = [os.fsencode(part) for part in Path(text).parts]
        whole = os.fsencode(os.path.abspath(text))
    except UnicodeError:
        raise WriteError(f"{shown}: {what}: the name cannot be written on this file system "
                         "(invalid characters); give a plain file name", errno.EINVAL) from None
    longest = max((len(b) for b in parts), default=0)
    if longest > NAME_MAX:
        raise WriteError(f"{shown}: {what}: a name of {longest} bytes; the file system "
                         f"allows {NAME_MAX}: choose a shorter one", errno.ENAMETOOLONG)
    if len(whole) >= PATH_MAX:
        raise WriteError(f"{shown}: {what}: the path is {len(whole)} bytes long; the file "
                         f"system allows {PATH_MAX - 1}: choose a shorter one",
                         errno.ENAMETOOLONG)
    return Path(text)


def _stat(p: Path) -> os.stat_result | None:
    try:
        return p.stat()
    except (OSError, ValueError):
        return None


def check_output_path(path: str | os.PathLike, what: str = "--out",
                      not_same_as: Mapping[str, str | os.PathLike] | None = None,
                      folder_must_exist: bool = False) -> Path:
    """Refuse an output path that is a folder, a name the file system cannot hold, or would
    overwrite one of ``not_same_as`` (e.g. an input or the camera file), or
    (``folder_must_exist``) whose folder is missing, before any work is done.

    Raises:
        WriteError: the path cannot be an output.
    """
    p = check_output_name(path, what)
    st = _stat(p)
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise WriteError(f"{p}: {what} is a folder; give a file name", errno.EISDIR)
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise WriteError(f"{p}: {what} is not a regular file; give a file name", errno.EINVAL)
    parent = _stat(p.absolute().parent)
    if folder_must_exist and (parent is None or not stat.S_ISDIR(parent.st_mode)):
        raise WriteError(f"{p}: {what}: the folder does not exist; create it or choose "
                         "another", errno.ENOENT)
    if parent is not None and stat.S_ISDIR(parent.st_mode) and not os.access(
            p.absolute().parent, os.W_OK | os.X_OK):
        raise WriteError(f"{p}: {what}: the folder is not writable; choose another",
                         errno.EACCES)
    _not_an_input(p, what, not_same_as)
    return p


def _real(p: str | os.PathLike) -> str:
    """``p`` absolute with every symbolic link that exists resolved (what a write to it would
    reach)."""
    try:
        return os.path.realpath(os.path.abspath(p))
    except (OSError, ValueError):
        return os.path.abspath(p)


def _same(p: Path, other: str | os.PathLike) -> bool:
    """Whether ``p`` and ``other`` name the same file (links and hard links included)."""
    if os.path.abspath(p) == os.path.abspath(other) or _real(p) == _real(other):
        return True
    try:
        return os.path.exists(other) and p.exists() and os.path.samefile(p, other)
    except (OSError, ValueError):
        return False


def _within(p: Path, folder: str | os.PathLike) -> bool:
    """Whether ``p`` is ``folder`` or lies anywhere below it, links resolved."""
    inner, outer = _real(p), _real(folder)
    try:
        return os.path.commonpath([inner, outer]) == outer
    except ValueError:
        return False


def _is_folder(p: str | os.PathLike) -> bool:
    try:
        return os.path.isdir(p)
    except (OSError, ValueError):
        return False


def _read_from(p: Path, folder: str | os.PathLike) -> bool:
    """Whether writing ``p`` would change what a reader of the input ``folder`` reads: ``p``
    is the folder, one of its images or videos (a folder of pictures is read in name order,
    not below), or anything in a recording folder (its index names what it reads)."""
    if not _is_folder(folder) or not _within(p, folder):
        return False
    if _real(p) == _real(folder) or os.path.isfile(os.path.join(folder, "recording.json")):
        return True
    # deferred: images loads numpy, which the command line's start does not need
    from drovisio.images import IMAGE_SUFFIXES, VIDEO_SUFFIXES

    return (os.path.dirname(_real(p)) == _real(folder) and not p.name.startswith(".")
            and p.suffix.lower() in IMAGE_SUFFIXES | VIDEO_SUFFIXES)


def _not_an_input(p: Path, what: str,
                  not_same_as: Mapping[str, str | os.PathLike] | None) -> None:
    """Refuse ``p`` when it is one of the inputs, or would be one of the files an input
    folder's reader takes (an image among the images it reads, anything in a recording)."""
    for label, other in (not_same_as or {}).items():
        if _read_from(p, other):
            raise WriteError(f"{p}: {what} would land among what the command reads from "
                             f"{label}; choose another folder", errno.EEXIST)
        if _same(p, other):
            raise WriteError(f"{p}: {what} is the same file as {label}; writing it would "
                             "destroy it: choose another name", errno.EEXIST)


#: options that name files a command reads, in every command (argparse destinations)
INPUT_OPTIONS = ("camera", "layout", "mount", "gravity_file", "inputs", "images", "protocol",
                 "scenario", "source")
#: options that name a file a command writes
OUTPUT_FILE_OPTIONS = ("out", "pdf", "report", "json")
#: options that name a folder a command writes into
OUTPUT_FOLDER_OPTIONS = ("record",)
#: commands whose ``--out`` is a folder
FOLDER_OUT_COMMANDS = ("study", "synth")

FILE, FOLDER, APPENDED = "file", "folder", "appended"
"""Kinds of output for :func:`check_outputs`: a file replaced whole, a folder written into,
a file appended to (a ``jsonl:PATH`` sink: it may be a device or a pipe)."""


def check_outputs(outputs: list[tuple[str, str | os.PathLike, str]],
                  inputs: Mapping[str, str | os.PathLike]) -> None:
    """The one check of a command's outputs before it starts: each is a name the file system
    can hold, of the right kind (a file or a folder), neither an input nor inside an input
    folder, and the outputs are distinct (no two the same file, none inside an output folder).

    Args:
        outputs: (option as said, path, kind: :data:`FILE`, :data:`FOLDER` or
            :data:`APPENDED`).
        inputs: What the command reads: label (the option and value) -> path.

    Raises:
        WriteError: one line naming the option and what to do.
    """
    checked: list[tuple[str, Path, str]] = []
    for what, path, kind in outputs:
        p = check_output_name(path, what)
        if kind == FILE:
            check_output_path(p, what, inputs)
        else:
            st = _stat(p)
            if kind == FOLDER and st is not None and not stat.S_ISDIR(st.st_mode):
                raise WriteError(f"{p}: {what} is a file; give a folder", errno.ENOTDIR)
            _not_an_input(p, what, inputs)
        for other_what, q, other_kind in checked:
            if _same(p, q):
                both = "given twice" if what == other_what else f"the same file as {other_what}"
                raise WriteError(f"{p}: {what} is {both}; give each output its own name",
                                 errno.EEXIST)
            for inner, inner_what, outer, outer_what, outer_kind in (
                    (p, what, q, other_what, other_kind), (q, other_what, p, what, kind)):
                if outer_kind == FOLDER and _within(inner, outer):
                    raise WriteError(f"{inner}: {inner_what} lies inside {outer_what}'s "
                                     f"folder {outer}; give it a place outside",
                                     errno.EEXIST)
        checked.append((what, p, kind))


def guard_outputs(args: object) -> None:
    """The one output guard of the command line, run before any command starts: every output
    option (``--out``, ``--pdf``, ``--report``, ``--json``, ``--record``, a ``jsonl:PATH``
    sink) goes through :func:`check_outputs` against the command's inputs
    (``calibrate mount --camera cam.yaml --out cam.yaml`` would replace the camera file,
    ``detect --out frames/a.jpg frames`` an image it reads).

    Args:
        args: The parsed command line (an ``argparse.Namespace``).

    Raises:
        WriteError: one line naming the option and what to do.
    """
    inputs: dict[str, str] = {}
    for name in INPUT_OPTIONS:
        v = getattr(args, name, None)
        for item in (v if isinstance(v, (list, tuple)) else [v]):
            if isinstance(item, (str, os.PathLike)) and os.fspath(item):
                opt = "input" if name in ("inputs", "images") else f"--{name.replace('_', '-')}"
                inputs.setdefault(f"{opt} {one_line(os.fspath(item), 120)}", os.fspath(item))
    command = getattr(args, "command", "")
    outputs: list[tuple[str, str | os.PathLike, str]] = []
    for name in OUTPUT_FILE_OPTIONS:
        v = getattr(args, name, None)
        if isinstance(v, (str, os.PathLike)):
            folder = command in FOLDER_OUT_COMMANDS and name == "out"
            outputs.append((f"--{name}", v, FOLDER if folder else FILE))
    for name in OUTPUT_FOLDER_OPTIONS:
        v = getattr(args, name, None)
        if isinstance(v, (str, os.PathLike)):
            # --record FILE.mcap is a file (the start-up check refuses an existing one)
            is_file = name == "record" and os.fspath(v).lower().endswith(".mcap")
            outputs.append((f"--{name}", v, FILE if is_file else FOLDER))
    for spec in getattr(args, "sink", None) or []:
        if isinstance(spec, str) and spec.strip().startswith("jsonl:") \
                and spec.strip() != "jsonl:-":
            path = spec.strip()[len("jsonl:"):]
            outputs.append(("--sink jsonl:PATH", path, APPENDED))
    check_outputs(outputs, inputs)


def output_folder(path: str | os.PathLike, what: str = "--out") -> Path:
    """A folder to write into, made if missing (an existing one is written into: its files
    of the same names are replaced, each atomically).

    Raises:
        WriteError: the path is a file, or the folder cannot be made.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise WriteError(f"{p}: {what} is a file; give a folder", errno.ENOTDIR)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise WriteError(f"{p}: {what}: the folder cannot be made ({e.strerror or e})",
                         e.errno or errno.EIO) from None
    if not os.access(p, os.W_OK):
        raise WriteError(f"{p}: {what}: the folder is not writable", errno.EACCES)
    return p


def atomic_write(path: str | os.PathLike, write_to_tmp: Callable[[Path], None], *,
                 overwrite: bool = True, mode: int | None = None, suffix: str = ".tmp",
                 make_parents: bool = False,
                 verify: Callable[[Path], None] | None = None,
                 allow_empty: bool = False) -> Path:
    """Write ``path`` through ``write_to_tmp(tmp_path)``, a check and a rename.

    Args:
        path: The file to write.
        write_to_tmp: Writes the content to the temporary path it is given.
        overwrite: Replace an existing file; False: raise :class:`FileExistsError` if the file
            exists (checked atomically with a hard link where the file system has them).
        mode: Permission bits of the new file (default: those of the file it replaces, else
            0o666 less the umask).
        suffix: Of the temporary file's name (some writers choose the format by it).
        make_parents: Create missing folders; False: a missing folder is an error.
        verify: Called with the temporary path once it is written and flushed; raises (any
            exception) if the content is not what was meant. Nothing is replaced then.
        allow_empty: Accept a 0-byte result (otherwise a writer that wrote nothing, as
            OpenCV's FileStorage does on a full disk, is an error).

    Returns:
        The path written.

    Raises:
        WriteError: The file could not be written or did not check out; the old one is kept.
        FileExistsError: ``overwrite`` is False and the file exists.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    try:
        if make_parents:
            folder.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}-", suffix=suffix, dir=folder)
        os.close(fd)
    except OSError as e:
        raise _explain(path, e) from None
    tmp = Path(tmp_name)
    try:
        try:
            write_to_tmp(tmp)
            with open(tmp, "rb+") as f:  # the writer may not have flushed to the disk
                os.fsync(f.fileno())
            size = tmp.stat().st_size
        except OSError as e:
            raise _explain(path, e) from None
        if size == 0 and not allow_empty:
            raise WriteError(f"{path}: not written: the result was empty (is the disk "
                             "full?); any previous file is kept", errno.EIO)
        if verify is not None:
            try:
                verify(tmp)
            except OSError as e:
                raise _explain(path, e) from None
            except Exception as e:  # noqa: BLE001 - any mismatch: keep the old file
                raise WriteError(f"{path}: not written: reading it back failed ({e}); any "
                                 "previous file is kept", errno.EIO) from None
        if mode is None:
            try:
                mode = stat.S_IMODE(path.stat().st_mode)
            except OSError:
                mode = 0o666 & ~_UMASK
        try:
            os.chmod(tmp, mode)
            if overwrite:
                os.replace(tmp, path)
            else:
                try:
                    os.link(tmp, path)          # atomic, and fails if path appeared meanwhile
                except FileExistsError:
                    raise
                except OSError:                 # no hard links on this file system
                    if path.exists():
                        raise FileExistsError(path) from None
                    os.replace(tmp, path)
        except FileExistsError:
            raise
        except OSError as e:
            raise _explain(path, e) from None
        _sync_folder(folder)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _sync_folder(folder: Path) -> None:
    """Make the rename itself durable (best effort: not every file system allows it)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, **kw) -> Path:
    """:func:`atomic_write` of ``data``; the written bytes are read back and compared."""
    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()

    outer = kw.pop("verify", None)

    def verify(tmp: Path) -> None:
        if tmp.read_bytes() != data:
            raise ValueError("the bytes on the disk differ from those written")
        if outer is not None:
            outer(tmp)

    kw.setdefault("allow_empty", not data)
    return atomic_write(path, write, verify=verify, **kw)


def atomic_write_text(path: str | os.PathLike, text: str, **kw) -> Path:
    """:func:`atomic_write_bytes` of UTF-8 ``text``."""
    return atomic_write_bytes(path, text.encode("utf-8"), **kw)


def save_figure(fig, path: str | os.PathLike, **savefig_kw) -> Path:
    """A matplotlib figure written through :func:`atomic_write` (matplotlib writes in place:
    a full disk would leave the old figure truncated). The format is the path's suffix."""
    path = Path(path)
    fmt = path.suffix.lstrip(".").lower() or "png"

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            fig.savefig(f, format=fmt, **savefig_kw)
            f.flush()

    def verify(tmp: Path) -> None:
        if fmt == "png":
            with open(tmp, "rb") as f:
                if f.read(8) != b"\x89PNG\r\n\x1a\n":
                    raise ValueError("not a PNG file")

    return atomic_write(path, write, suffix=path.suffix or ".png", verify=verify)


def write_image(path: str | os.PathLike, image, params: list[int] | None = None) -> Path:
    """An OpenCV image written through :func:`atomic_write` and decoded back (``cv2.imwrite``
    writes in place and says only False on a full disk)."""
    import cv2

    path = Path(path)
    ok, buf = cv2.imencode(path.suffix or ".png", image, params or [])
    if not ok:
        raise WriteError(f"{path}: not written: OpenCV cannot encode an image as "
                         f"{path.suffix!r}; use .png or .jpg", errno.EINVAL)
    return atomic_write_bytes(path, buf.tobytes())


def write_video(path: str | os.PathLike, frames, fps: float, size: tuple[int, int],
                fourcc: str = "mp4v") -> Path:
    """A video written through :func:`atomic_write`: OpenCV's VideoWriter writes in place
    (and says nothing on a full disk), so it writes beside, the video is opened back and its
    frames counted, and only then it replaces the old file.

    Args:
        path: The video file (its suffix chooses the container).
        frames: BGR images of ``size`` (width, height), pixels.
        fps: Frames per second written in the container.
        size: (width, height) of every frame, pixels.
        fourcc: The codec's four characters.
    """
    import cv2

    path = Path(path)
    frames = list(frames)

    def write(tmp: Path) -> None:
        w = cv2.VideoWriter(str(tmp), cv2.VideoWriter.fourcc(*fourcc), float(fps),
                            (int(size[0]), int(size[1])))
        if not w.isOpened():
            raise OSError(errno.EIO, "OpenCV cannot write this video (codec or container)")
        try:
            for img in frames:
                w.write(img)
        finally:
            w.release()

    def verify(tmp: Path) -> None:
        cap = cv2.VideoCapture(str(tmp))
        try:
            n = 0
            while n < len(frames) and cap.read()[0]:
                n += 1
        finally:
            cap.release()
        if n != len(frames):
            raise ValueError(f"{n} of {len(frames)} frames could be read back")

    return atomic_write(path, write, suffix=path.suffix or ".mp4", verify=verify)


def _identity(st: os.stat_result) -> tuple[int, int]:
    return st.st_dev, st.st_ino


class MadeFiles:
    """The files and folders an output made, each known by its inode, for :meth:`remove` to
    remove again when nothing was written to them at close (a recording with no frame): a
    run that ended before its first frame leaves nothing behind, and the next run may write to
    the same name.

    Nothing that was there before is among them. A path that no longer names what was made
    (replaced or moved meanwhile) is left alone, and so is a folder something else was put
    in, with every folder above it.
    """

    def __init__(self) -> None:
        self._files: list[tuple[Path, tuple[int, int]]] = []
        self._folders: list[tuple[Path, tuple[int, int]]] = []   # deepest first

    def make_folder(self, folder: Path) -> None:
        """``folder`` and its missing parents made (as ``mkdir -p``); those this call made
        are noted.

        Raises:
            OSError: a folder could not be made.
        """
        missing = []
        for q in (folder, *folder.parents):
            if q.exists() or q.is_symlink():
                break
            missing.append(q)
        for q in reversed(missing):   # outermost first
            try:
                q.mkdir()
                self._folders.insert(0, (q, _identity(q.lstat())))
            except FileExistsError:
                continue   # made meanwhile by something else: not ours
            except OSError:
                break      # said by the mkdir below
        folder.mkdir(parents=True, exist_ok=True)

    def add(self, path: Path, st: os.stat_result) -> None:
        """Note a file made here; ``st``: the status of what was written."""
        self._files.append((path, _identity(st)))

    def remove(self) -> bool:
        """Remove the files made here, then the folders made here that are then empty
        (deepest first); whether every file made here is gone."""
        gone = True
        for path, ident in self._files:
            try:
                if _identity(path.lstat()) == ident:
                    path.unlink()
                else:
                    gone = False
            except FileNotFoundError:
                pass
            except OSError:
                gone = False
        self._files = []
        for q, ident in self._folders:
            try:
                if _identity(q.lstat()) != ident:
                    break
                q.rmdir()
            except OSError:
                break   # something else is in it: it stays, and so does every folder above
        self._folders = []
        return gone
