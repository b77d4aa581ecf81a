"""The bases of every area's schemas: request bodies and response models.

Request bodies (:class:`Body`) refuse unknown fields and non-finite numbers. Response models
(:class:`Answer`) describe the JSON bodies the routes answer with (the OpenAPI document at
``/api/docs``); the services build those bodies and the routes send them as they are (through
:class:`webtool.responses.JSONResponse`), so a model names the keys a page reads, and a body may
carry more (``extra="allow"``).
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict

__all__ = ["Answer", "Body", "Detail", "Json", "SceneLink"]

#: a JSON value the model does not describe further
Json = Any


class Body(BaseModel):
    """Every request body: no unknown fields, finite numbers only."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Answer(BaseModel):
    """Every response model: the keys a page reads (a body may carry more)."""

    model_config = ConfigDict(extra="allow")


class Detail(Answer):
    """An error, in plain words (every 4xx and 5xx answer)."""

    detail: str


class SceneLink(Answer):
    """Where an area's 3D view is served (through this app) and its viser port."""

    url: str
    port: int | None
