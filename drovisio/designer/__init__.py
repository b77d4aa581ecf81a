"""Marker designer core: place ArUco codes and colour dots on a brick's mesh, check the
design, export the layout file, a GLB and true-scale print sheets.

No web imports here: the web tool (``webtool/designer_scene.py``, ``webtool/routes/designer.py``)
drives :class:`drovisio.designer.model.DesignDocument`.

Modules:
    * :mod:`.raycast` - viewer click ray -> point/face on the mesh (trimesh + rtree).
    * :mod:`.model` - the editable document (mesh files and units, code dictionaries, the
      brick frame, markers, click modes, undo), one subject per module.
    * :mod:`.checks` - live warnings (overhang, overlap, coplanarity, symmetry, ids, range)
      and the one-click fixes.
    * :mod:`.fitting` - a marker on its face: fits, largest size that fits, overlaps.
    * :mod:`.symmetry` - the turns that map a dot pattern onto itself, and breaking them.
    * :mod:`.export` - layout JSON, GLB, print sheet PDF/SVG, saving into a layouts folder.
    * :mod:`.verify` - a rendered view of the design read back by the detectors.
"""

from drovisio.designer.model import DesignDocument, DesignError, DesignMarker

__all__ = ["DesignDocument", "DesignError", "DesignMarker"]
