"""The health check's response model (``GET /api/health``)."""

from __future__ import annotations

from pydantic import BaseModel

__all__ = ["Health"]


class Health(BaseModel):
    status: str
    version: str
    source: str  # the --source given, or the sample session folder
    sample: bool  # True when running on the built-in sample session
