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

from drovisio.errors import WriteError

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text", "check_output_path",
           "output_folder"]


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


def check_output_path(path: str | os.PathLike, what: str = "--out",
                      not_same_as: Mapping[str, str | os.PathLike] | None = None,
                      folder_must_exist: bool = False) -> Path:
    """Refuse an output path that is a folder or would overwrite one of ``not_same_as``
    (e.g. an input or the camera file), or (``folder_must_exist``) whose folder is missing,
    before any work is done.

    Raises:
        WriteError: the path cannot be an output.
    """
    p = Path(path)
    if p.is_dir():
        raise WriteError(f"{p}: {what} is a folder; give a file name", errno.EISDIR)
    if p.exists() and not p.is_file():
        raise WriteError(f"{p}: {what} is not a regular file; give a file name", errno.EINVAL)
    if folder_must_exist and not p.absolute().parent.is_dir():
        raise WriteError(f"{p}: {what}: the folder does not exist; create it or choose "
                         "another", errno.ENOENT)
    for label, other in (not_same_as or {}).items():
        o = Path(other)
        try:
            same = o.exists() and p.exists() and os.path.samefile(p, o)
        except OSError:
            same = False
        if same or os.path.abspath(p) == os.path.abspath(o):
            raise WriteError(f"{p}: {what} is the same file as {label}; writing it would "
                             "destroy it: choose another name", errno.EEXIST)
    return p


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
