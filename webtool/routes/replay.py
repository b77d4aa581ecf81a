"""The replay area's routers (:mod:`webtool.replay.routes`)."""

from webtool.replay.routes import router, viewer_router

__all__ = ["router", "viewer_router"]
