"""The fleet area's routers (:mod:`webtool.fleet.routes`)."""

from webtool.fleet.routes import router, viewer_router

__all__ = ["router", "viewer_router"]
