"""The study area's routers (:mod:`webtool.study.routes`)."""

from webtool.study.routes import router, viewer_router

__all__ = ["router", "viewer_router"]
