"""The designer area's routers (:mod:`webtool.designer.routes`)."""

from webtool.designer.routes import router, viewer_router

__all__ = ["router", "viewer_router"]
