"""Sample sessions made by drovisio's renderer (data package: see drovisio.resources)."""
