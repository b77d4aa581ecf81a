"""Marker layouts shipped with Drovisio (data package: see drovisio.resources)."""
