"""The marker designer's editable document and what it is made of.

The public face of the designer's model (import from ``drovisio.designer.model``):

* :mod:`.document` - :class:`DesignDocument`, the document the web page edits.
* :mod:`.meshfile` - uploaded mesh files: format sniffing, reading, their length unit.
* :mod:`.codes` - code families and the dictionary holding a design's id block.
* :mod:`.frame` - the brick frame on the mesh (``brick_from_mesh``) and face directions.
* :mod:`.marker` - :class:`DesignMarker`, one marker in the mesh frame.
* :mod:`.modes` - the click modes and :class:`ClickResult`.
* :mod:`.edits` - checks on the values a user types.
* :mod:`.history` - undo and redo.
* :mod:`.errors` - :class:`DesignError`.

Everything is in metres and radians; degrees only in the arguments named ``*_deg``.
"""

from drovisio.designer.model.codes import code_families, dictionary_for_block
from drovisio.designer.model.document import DesignDocument
from drovisio.designer.model.errors import DesignError
from drovisio.designer.model.history import UNDO_LIMIT
from drovisio.designer.model.marker import DesignMarker
from drovisio.designer.model.meshfile import (
    MESH_TYPES,
    UNITS,
    guess_units,
    read_mesh,
    units_problem,
)
from drovisio.designer.model.modes import MODES, ClickResult, Mode

__all__ = [
    "MESH_TYPES", "UNITS", "MODES", "Mode", "UNDO_LIMIT", "DesignError", "DesignMarker",
    "DesignDocument", "ClickResult", "read_mesh", "guess_units", "units_problem",
    "code_families", "dictionary_for_block",
]
