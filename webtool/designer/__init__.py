"""The marker designer page: one design edited in this web tool.

``routes`` (the JSON API and the 3D view's proxy), ``service`` (the design, its lock and change
notifications), ``scene`` (the 3D view).
"""

from webtool.designer.service import DesignerService

__all__ = ["DesignerService"]
