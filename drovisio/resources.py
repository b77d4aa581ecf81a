"""The files shipped with Drovisio: marker layouts and their meshes, the sample sessions, the
mission scenarios, and the web tool's templates and static files.

They are installed with the package (``pyproject.toml`` maps the repository's top-level
``marker_layouts/``, ``sample_sessions/``, ``docs/`` and ``templates/`` folders into the
packages ``drovisio.marker_layouts``, ``drovisio.sample_sessions``, ``drovisio.docs`` and
``webtool.templates``) and found
through :mod:`importlib.resources`, so a wheel works like a checkout. In an editable install
(``make install``) these are the checkout's own folders.
"""

from __future__ import annotations

import os
from importlib.resources import files
from pathlib import Path

__all__ = [
    "DATA_ENV",
    "docs_dir",
    "layouts_dir",
    "sample_sessions_dir",
    "scenarios_dir",
    "static_dir",
    "templates_dir",
    "user_data_dir",
]


def _dir(package: str) -> Path:
    return Path(str(files(package)))


def layouts_dir() -> Path:
    """The shipped marker layouts (``*.json``) and their ``meshes/``."""
    return _dir("drovisio.marker_layouts")


def sample_sessions_dir() -> Path:
    """The sample sessions the tool runs on without a camera (``make samples`` rewrites
    them)."""
    return _dir("drovisio.sample_sessions")


def scenarios_dir() -> Path:
    """The shipped mission scenarios (``*.yaml``)."""
    return _dir("drovisio.mission.scenarios")


def docs_dir() -> Path:
    """The field guide (``field-guide.md``) and its screenshots (``images/``)."""
    return _dir("drovisio.docs")


def templates_dir() -> Path:
    """The web tool's Jinja2 pages."""
    return _dir("webtool.templates")


def static_dir() -> Path:
    """The web tool's scripts, styles and pictures."""
    return _dir("webtool.static")


DATA_ENV = "DROVISIO_DATA"


def user_data_dir(*parts: str) -> Path:
    """The user's data folder: what the tool keeps of what the user makes (calibration
    sessions, the calibration and mount in use, saved layouts, study reports), never inside
    the checkout or the installed package.

    ``$DROVISIO_DATA`` when set (``drovisio serve --data DIR`` gives one server its own),
    else ``$XDG_DATA_HOME/drovisio`` (default ``~/.local/share/drovisio``).
    """
    own = os.environ.get(DATA_ENV)
    if own:
        return Path(own, *parts)
    base = os.environ.get("XDG_DATA_HOME") or os.path.join(os.path.expanduser("~"), ".local",
                                                           "share")
    return Path(base, "drovisio", *parts)
