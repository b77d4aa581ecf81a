"""Jinja2 pages of the web tool (data package: see drovisio.resources)."""
