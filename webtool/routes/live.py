"""The live area's routers (:mod:`webtool.live.routes`)."""

from webtool.live.routes import router, viewer_router

__all__ = ["router", "viewer_router"]
