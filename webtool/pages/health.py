"""GET /api/health: is the tool up, which version, on which source."""


from fastapi import APIRouter, Request
from pydantic import BaseModel

from webtool.deps import CurrentSettings

router = APIRouter(prefix="/api", tags=["health"])


class Health(BaseModel):
    status: str
    version: str
    source: str  # the --source given, or the sample session folder
    sample: bool  # True when running on the built-in sample session


@router.get("/health", response_model=Health)
def health(request: Request, settings: CurrentSettings) -> Health:
    return Health(
        status="ok",
        version=request.app.version,
        source=settings.source if settings.source is not None else str(settings.sample_session),
        sample=settings.uses_sample_session,
    )
