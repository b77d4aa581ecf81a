"""The HTML pages (start page, the parts of the tool, the field guide) and the health
check.

``routes`` (the pages), ``health`` (``GET /api/health``).
"""
