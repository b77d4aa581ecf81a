"""The field guide (``field-guide.md``) and its screenshots (``images/``), installed as
``drovisio.docs`` and shown on the web tool's Help page. The screenshots are written by the
browser tests (tests/browser/test_field_guide.py), so they show the pages as they are."""
