"""Writing files so that nothing already saved is lost: through a temporary file in the same
folder, then renamed over the target (a reader, or a crash, sees the old file or the new one).

One mechanism for every file the project writes (camera files, layouts, meshes, reports,
calibration sessions); callers translate the exceptions into their own messages.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

__all__ = ["atomic_write", "atomic_write_bytes"]


def atomic_write(path: str | os.PathLike, write_to_tmp: Callable[[Path], None], *,
                 overwrite: bool = True, mode: int | None = None, suffix: str = ".tmp",
                 make_parents: bool = False) -> Path:
    """Write ``path`` through ``write_to_tmp(tmp_path)`` and a rename.

    Args:
        path: The file to write.
        write_to_tmp: Writes the content to the temporary path it is given.
        overwrite: Replace an existing file; False: raise :class:`FileExistsError` if the file
            exists (checked atomically with a hard link where the file system has them).
        mode: Permission bits of the new file (default: the temporary file's, 0o600).
        suffix: Of the temporary file's name (some writers choose the format by it).
        make_parents: Create missing folders; False: a missing folder raises
            :class:`FileNotFoundError`.

    Returns:
        The path written.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if make_parents:
        folder.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}-", suffix=suffix, dir=folder)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        write_to_tmp(tmp)
        if mode is not None:
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
    finally:
        tmp.unlink(missing_ok=True)
    return path


def atomic_write_bytes(path: str | os.PathLike, data: bytes, **kw) -> Path:
    """:func:`atomic_write` of ``data``, flushed to the disk before the rename."""
    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    return atomic_write(path, write, **kw)
