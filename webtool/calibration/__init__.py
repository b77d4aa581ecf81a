"""The calibration page: a live calibration session fed by the server's camera.

``routes`` (the JSON API), ``service`` (the session, its camera and its solves).
"""

from webtool.calibration.service import CalibrationService, camera_in_use

__all__ = ["CalibrationService", "camera_in_use"]
