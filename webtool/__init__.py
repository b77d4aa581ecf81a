"""Drovisio's web tool: a FastAPI app (``webtool.app.create_app``) served by ``drovisio serve``."""
