"""The live view: the pipeline of this server, its image stream and its 3D scene.

``routes`` (the JSON API and the streams), ``service`` (the pipeline and the adaptive stream),
``scene`` (the 3D view).
"""

from webtool.live.service import LiveService

__all__ = ["LiveService"]
