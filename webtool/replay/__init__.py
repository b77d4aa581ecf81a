"""The mission replay panel of the live page: simulated mission recordings played back.

``routes`` (the JSON API), ``service`` (the recordings and the playback), ``scene`` (the 3D
view).
"""

from webtool.replay.service import ReplayService

__all__ = ["ReplayService"]
