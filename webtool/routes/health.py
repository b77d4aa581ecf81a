"""The health check's router (:mod:`webtool.pages.health`)."""

from webtool.pages.health import router

__all__ = ["router"]
