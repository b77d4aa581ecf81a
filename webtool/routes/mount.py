"""The mount area's routers (:mod:`webtool.mount.routes`)."""

from webtool.mount.routes import router, viewer_router

__all__ = ["router", "viewer_router"]
