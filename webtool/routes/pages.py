"""The HTML pages' router (:mod:`webtool.pages.routes`)."""

from webtool.pages.routes import router

__all__ = ["router"]
