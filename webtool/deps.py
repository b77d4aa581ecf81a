"""Small dependencies shared by the routers."""

from fastapi import Request
from fastapi.templating import Jinja2Templates

from webtool.settings import Settings


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_templates(request: Request) -> Jinja2Templates:
    return request.app.state.templates
