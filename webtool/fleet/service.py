"""The Fleet page's service: the station's Zenoh link and fleet state, and its 3D scene.

Made on first use of the area (``drovisio station`` asks for it at start, so drones are heard
before anyone opens the page) from the settings' ``station_listen`` / ``station_connect``
endpoints; a web tool started by ``drovisio serve`` has none and its Fleet page says so.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from drovisio.station import Fleet, StationLink
from webtool.errors import NotFound, Unavailable
from webtool.fleet.scene import FleetScene
from webtool.settings import Settings

__all__ = ["FleetService"]

log = logging.getLogger("webtool.fleet")


class FleetService:
    """The station of this web tool (module doc).

    Args:
        settings: The app's settings (``station_listen``, ``station_connect``,
            ``station_domain``).
    """

    def __init__(self, settings: Settings):
        self.settings = settings
        self.fleet = Fleet()
        self.error: str | None = None
        self.link: StationLink | None = None
        self._scene: FleetScene | None = None
        self._lock = threading.Lock()
        if settings.station_listen or settings.station_connect:
            try:
                self.link = StationLink(self.fleet, listen=list(settings.station_listen),
                                        connect=list(settings.station_connect),
                                        domain=settings.station_domain)
            except Exception as e:  # noqa: BLE001 - said on the page and at start-up
                self.error = f"cannot listen for drones: {e}"
                log.error("%s", self.error)

    def status(self) -> dict[str, Any]:
        """The page's table: every drone heard, and where this station listens."""
        return {"drones": [d.to_json() for d in self.fleet.status()],
                "listen": list(self.settings.station_listen),
                "connect": list(self.settings.station_connect),
                "lost_after_s": self.fleet.lost_after_s, "error": self.error}

    def image(self, drone: str) -> bytes:
        """A drone's latest camera thumbnail (JPEG)."""
        jpeg, _ = self.fleet.image(drone)
        if jpeg is None:
            raise NotFound(f"no camera image from drone {drone!r} yet")
        return jpeg

    def start_scene(self) -> FleetScene:
        with self._lock:
            scene = self._scene
            if scene is None:
                scene = FleetScene(self.fleet)
                try:
                    scene.start()
                except Exception as e:  # noqa: BLE001
                    raise Unavailable(f"the 3D view could not start: {e}") from e
                self._scene = scene
            return scene

    def close(self) -> None:
        with self._lock:
            if self._scene is not None:
                self._scene.stop()
                self._scene = None
        if self.link is not None:
            self.link.close()
            self.link = None
