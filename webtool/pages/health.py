"""GET /api/health: is the tool up, which version, on which source."""


from fastapi import APIRouter, Request

from webtool.deps import CurrentSettings
from webtool.pages.schemas import Health

router = APIRouter(prefix="/api", tags=["health"])


@router.get("/health", response_model=Health)
def health(request: Request, settings: CurrentSettings) -> Health:
    return Health(
        status="ok",
        version=request.app.version,
        source=settings.source if settings.source is not None else str(settings.sample_session),
        sample=settings.uses_sample_session,
    )
