"""Scripts, styles and pictures of the web tool (data package: see drovisio.resources)."""
