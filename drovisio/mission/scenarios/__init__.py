"""Shipped mission scenarios (data package: see drovisio.resources)."""
