"""The calibration area's routers (:mod:`webtool.calibration.routes`)."""

from webtool.calibration.routes import router

__all__ = ["router"]
