"""Reading the small text files users give (camera, layout, mount, scenario, gravity, protocol):
bounded in size, nesting and YAML aliases, and never blocking on something that is not a file.

Every function raises :class:`~drovisio.errors.InputError` with a one-line message that names
the file; the callers add the field.
"""

from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path
from typing import Any

import yaml

from drovisio.errors import LIMITS, InputError, one_line

__all__ = ["BoundedYamlLoader", "check_regular_file", "missing_reason", "name_inside",
           "parse_json", "parse_yaml", "path_text_problem", "read_bytes", "read_inside",
           "read_structured", "read_text", "resolve_inside", "unreachable"]


def unreachable(path: str | os.PathLike, e: OSError) -> str:
    """Why an input path could not be opened, in words, without the path (callers add it): a
    missing file, a symbolic link to nothing, a loop of symbolic links (which the system and
    ``Path.exists()`` answer like a missing file), or what the system said."""
    if e.errno == errno.ELOOP:
        return ("a loop of symbolic links (they lead to each other, never to a file or "
                "folder); give the real path")
    if e.errno in (errno.ENOENT, errno.ENOTDIR):
        if os.path.islink(path):
            return "a symbolic link to nothing (its target does not exist); give the real path"
        return "no such file or folder"
    return f"cannot be read ({e.strerror or e})"


def missing_reason(path: str | os.PathLike) -> str | None:
    """None when ``path`` leads to something (a file, a folder, a device), else why not
    (:func:`unreachable`)."""
    try:
        os.stat(path)
    except OSError as e:
        return unreachable(path, e)
    except ValueError:  # a NUL byte
        return "the name contains a NUL byte; give a real file name"
    return None


def check_regular_file(path: str | os.PathLike, what: str = "file") -> Path:
    """``path`` if it is a regular file; a clear error for a missing path, a folder, or a FIFO,
    socket or device (reading those can block forever)."""
    p = Path(path)
    if "\x00" in str(p):
        raise InputError(f"{one_line(repr(str(p)), 120)}: the {what}'s name contains a NUL "
                         "byte; give a real file name")
    try:
        st = p.stat()
    except OSError as e:
        if e.errno == errno.ENOENT and not p.is_symlink():
            raise InputError(f"{p}: {what} not found") from None
        why = (f"the {what} is {unreachable(p, e)}" if e.errno in (errno.ELOOP, errno.ENOENT)
               else f"cannot read the {what} ({e.strerror or e})")
        raise InputError(f"{one_line(p, 160)}: {why}") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{p}: is a folder; give the {what} itself")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{p}: not a regular file (a pipe or device); give the {what} itself")
    return p


def _amount(n: int) -> str:
    """A byte limit in words: KiB up to 16 MiB (the text files' limit), MiB above."""
    return f"{n // 2**20} MiB" if n > 16 * 2**20 else f"{n // 1024} KiB"


def read_bytes(path: str | os.PathLike, what: str = "file",
               max_bytes: int | None = None) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (default
    :attr:`~drovisio.errors.Limits.max_file_bytes`): a larger one is refused from its size,
    before anything is read (a sparse file of terabytes costs nothing)."""
    p = check_regular_file(path, what)
    limit = LIMITS.max_file_bytes if max_bytes is None else max_bytes
    try:
        with open(p, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            data = f.read(limit + 1) if size <= limit else b""
    except OSError as e:
        raise InputError(f"{p}: cannot read the {what} ({e.strerror or e})") from None
    if size > limit or len(data) > limit:   # the second: a file that grew while read
        raise InputError(f"{p}: the {what} is larger than {_amount(limit)}; is it the "
                         "right file?")
    return data


def read_text(path: str | os.PathLike, what: str = "file",
              max_bytes: int | None = None) -> str:
    """The UTF-8 text of a small file (:func:`read_bytes`)."""
    data = read_bytes(path, what, max_bytes)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise InputError(f"{Path(path)}: not UTF-8 text (byte {e.start}); the {what} must be a "
                         "text file") from None


def path_text_problem(name: str) -> str | None:
    """What makes ``name`` (a path written inside a file) unusable as a path, or None: a NUL
    byte or control character, a name over 255 bytes, a path over 1024 (the OS would answer
    with ``ValueError`` or ``Errno 36`` deep inside some reader)."""
    if "\x00" in name or any(ord(ch) < 32 for ch in name):
        return "contains a NUL byte or a control character; give a plain file name"
    try:
        encoded = [os.fsencode(part) for part in Path(name).parts]
    except UnicodeError:
        return "cannot be a file name on this system; give a plain file name"
    if sum(len(b) for b in encoded) > 1024 or any(len(b) > 255 for b in encoded):
        return "is too long for a file name (255 bytes a name); give a shorter one"
    return None


def name_inside(folder: str | os.PathLike, name: object, where: str,
                what: str = "file") -> Path:
    """``folder / name`` for a name read from a field of a file in ``folder``, checked as
    text only (nothing is opened: an index of a million frames is checked at once): a
    relative name that stays inside ``folder`` (no ``..`` out of it, no absolute path), with
    no NUL byte, a name the file system can hold. ``where`` is ``FILE: FIELD``.

    Raises:
        InputError: ``where: what is wrong and what to do``.
    """
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"{where}: give the {what}'s name as text, relative to the folder "
                         f"{folder}")
    shown = one_line(repr(name), 120)
    problem = path_text_problem(name)
    if problem:
        raise InputError(f"{where}: {shown} {problem}")
    base = Path(folder)
    if Path(name).is_absolute():
        raise InputError(f"{where}: {shown} is an absolute path; name a file inside {base} "
                         "(relative to it)")
    if os.path.normpath(name).split(os.sep)[0] == os.pardir:
        raise InputError(f"{where}: {shown} is outside the folder {base}; only files inside "
                         "it are read: copy the file there")
    return base / name


def resolve_inside(folder: str | os.PathLike, name: object, where: str,
                   what: str = "file") -> Path:
    """The path a file names (``name``, read from a field of a file in ``folder``), checked
    before anything is opened: :func:`name_inside`, and a regular file that stays inside
    ``folder`` once links are followed. ``where`` is ``FILE: FIELD`` for the message.

    Raises:
        InputError: ``where: what is wrong and what to do``.
    """
    p = name_inside(folder, name, where, what)
    base = Path(folder)
    try:
        inside = p.resolve().is_relative_to(base.resolve())
    except (OSError, RuntimeError):  # a loop of links
        inside = False
    if not inside:
        raise InputError(f"{where}: {one_line(repr(name), 120)} is outside the folder {base}; "
                         "only files inside it are read: copy the file there")
    try:
        return check_regular_file(p, what)
    except InputError as e:
        raise InputError(f"{where}: {e}") from None


def read_inside(folder: str | os.PathLike, name: object, where: str, what: str = "file",
                max_bytes: int | None = None) -> str:
    """The text of the file a file names (see :func:`resolve_inside`), read within
    ``max_bytes`` (default :attr:`~drovisio.errors.Limits.max_file_bytes`): the one reader of
    every path that comes from inside a file (a recording's manifest, a protocol)."""
    p = resolve_inside(folder, name, where, what)
    try:
        return read_text(p, what, max_bytes)
    except InputError as e:
        raise InputError(f"{where}: {e}") from None


def _depth(obj: Any, limit: int) -> int:
    """Nesting depth of lists and dicts (iterative: hostile input must not exhaust the
    stack); stops counting once past ``limit``."""
    deepest = 0
    stack = [(obj, 1)]
    seen: set[int] = set()
    while stack:
        o, d = stack.pop()
        if isinstance(o, (dict, list)):
            if id(o) in seen:  # YAML aliases share objects; count each once
                continue
            seen.add(id(o))
            deepest = max(deepest, d)
            if deepest > limit:
                return deepest
            items = o.values() if isinstance(o, dict) else o
            stack.extend((v, d + 1) for v in items)
    return deepest


def _check_depth(obj: Any, source: str) -> Any:
    limit = LIMITS.max_json_depth
    if _depth(obj, limit) > limit:
        raise InputError(f"{source}: nested more than {limit} levels deep; this is not a file "
                         "Drovisio writes or reads")
    return obj


def _aliased_values(obj: Any, limit: int) -> int | None:
    """How many values YAML aliases add to ``obj`` once expanded (a list or mapping reached
    through several aliases counted each time), counting up to ``limit`` and past it at
    most by one container; None for an alias that holds itself (a loop). ``obj``'s nesting
    is already bounded (:func:`_check_depth`), which bounds the recursion."""
    whole: dict[int, int] = {}    # values of each container, its aliased ones expanded
    busy: set[int] = set()
    extra = 0

    def count(o: Any) -> int | None:
        nonlocal extra
        key = id(o)
        if key in whole:      # reached again: through an alias
            extra += whole[key]
            return whole[key]
        if key in busy:
            return None
        busy.add(key)
        n = len(o)
        for v in (o.values() if isinstance(o, dict) else o):
            if isinstance(v, (dict, list)):
                inner = count(v)
                if inner is None:
                    return None
                n += inner
            if extra > limit:
                break
        busy.discard(key)
        whole[key] = n
        return n

    if isinstance(obj, (dict, list)) and count(obj) is None:
        return None
    return extra


def _check_aliases(obj: Any, source: str) -> Any:
    """Refuse a YAML document whose aliases expand it by more than
    :attr:`~drovisio.errors.Limits.max_yaml_expanded` values: a hundred aliases of aliases
    (under the alias cap) name billions of values, which any reader that walks or quotes
    them (an error message included) would never finish; or an alias that holds itself."""
    limit = LIMITS.max_yaml_expanded
    extra = _aliased_values(obj, limit)
    if extra is None:
        raise InputError(f"{source}: a YAML alias holds itself (a loop); write the values "
                         "out instead")
    if extra > limit:
        raise InputError(f"{source}: its YAML aliases expand to more than {limit:,} values "
                         "(an alias bomb?); write the values out instead")
    return obj


def _refuse(name: str) -> Any:
    raise ValueError(name)


def _short_int(digits: str) -> int:
    if len(digits.lstrip("-")) > LIMITS.max_digits:
        raise ValueError(digits[:8])
    return int(digits)


#: parse_json's rules (no NaN or Infinity, at most LIMITS.max_digits digits) in one decoder
#: made once: a text it refuses is read again with the hooks that word the refusal (a
#: decoder made per call cost most of the time of a file of many short lines)
_STRICT = json.JSONDecoder(parse_constant=_refuse, parse_int=_short_int)


def parse_json(text: str | bytes, source: str, **kw: Any) -> Any:
    """JSON with its nesting bounded; finite numbers only (NaN and Infinity are refused,
    unless ``parse_constant`` is given: the caller then checks its fields' numbers itself)."""
    if not kw and isinstance(text, str):
        try:
            data = _STRICT.decode(text)
        except (ValueError, RecursionError):
            pass   # said below, in words
        else:
            return _check_depth(data, source)
    def no_constant(name: str) -> Any:
        raise InputError(f"{source}: {name} is not a number JSON allows; give a finite number")

    def bounded_int(digits: str) -> int:
        if len(digits.lstrip("-")) > LIMITS.max_digits:
            raise InputError(f"{source}: a number of {len(digits)} digits; give at most "
                             f"{LIMITS.max_digits}")
        return int(digits)

    kw.setdefault("parse_int", bounded_int)
    kw.setdefault("parse_constant", no_constant)
    try:
        data = json.loads(text, **kw)
    except RecursionError:
        raise InputError(f"{source}: nested too deeply to be a Drovisio file") from None
    except json.JSONDecodeError as e:
        raise InputError(f"{source}: invalid JSON at line {e.lineno}, column {e.colno}: "
                         f"{e.msg}") from None
    except UnicodeDecodeError as e:
        raise InputError(f"{source}: not UTF-8 text (byte {e.start})") from None
    return _check_depth(data, source)


class BoundedYamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader with a cap on alias references (a "billion laughs" document
    makes every later step, down to the error message, explode)."""

    max_aliases = 100

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._aliases = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > self.max_aliases:
                raise yaml.YAMLError(f"more than {self.max_aliases} YAML aliases")
        return super().compose_node(parent, index)


def parse_yaml(text: str, source: str, loader: type[BoundedYamlLoader] | None = None) -> Any:
    """YAML (safe subset) with aliases, what they expand to, and nesting bounded (``loader``:
    a subclass of :class:`BoundedYamlLoader` that knows more tags)."""
    loader = loader or BoundedYamlLoader
    loader.max_aliases = LIMITS.max_yaml_aliases
    try:
        data = yaml.load(text, Loader=loader)  # noqa: S506 - a SafeLoader subclass
    except RecursionError:
        raise InputError(f"{source}: nested too deeply to be a Drovisio file") from None
    except ValueError as e:  # PyYAML converts numbers with int(): 4,300 digits is its limit
        raise InputError(f"{source}: {one_line(e, 160)}; give numbers of at most "
                         f"{LIMITS.max_digits} digits") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise InputError(f"{source}: not valid YAML{where}: {one_line(problem, 160)}") from None
    return _check_aliases(_check_depth(data, source), source)


def read_structured(path: str | os.PathLike, what: str = "file") -> Any:
    """A JSON (``.json``) or YAML (anything else) file, read and parsed within the limits
    above; errors are :class:`InputError` naming the file."""
    p = Path(path)
    text = read_text(p, what)
    return parse_json(text, str(p)) if p.suffix.lower() == ".json" else parse_yaml(text, str(p))
