"""Marker layouts: which markers a brick carries and where (``marker_layouts/*.json``).

One typed pydantic v2 model, :class:`MarkerLayout`, is the single source of truth for the
layout file format (contract: ``DESIGN.md``, "Marker layout file"). It validates files,
converts every problem into a :class:`LayoutError` that names the file, the marker and the
field, and emits the JSON Schema the web designer uses (:func:`layout_json_schema`).

Units: the model keeps the numbers in the file's ``units`` (so a layout written in
millimetres saves back in millimetres). Everything the rest of Drovisio consumes goes through
the ``*_m`` accessors, which return metres (convention: metres and radians inside).

Frames: all coordinates are in the brick frame defined by the layout. Shipped layouts put the
origin at the centre of the brick's top face, x along the length, y along the width, z up.

Ids: a layout with ArUco codes owns a block of ids. Instance ``k``'s code in slot ``s`` has
id ``first_id + k * ids_per_instance + s``.

Modules (this package's ``__init__`` is the public face; import from ``drovisio.layout``):

* :mod:`.dictionaries` - ArUco dictionary names, sizes, families and code bits.
* :mod:`.palette` - dot colours (:class:`ColorSpec`) and the default palette.
* :mod:`.square` - a square code's corners and the checks on given corners.
* :mod:`.markers` - the two marker kinds, :class:`ArucoMarker` and :class:`DotMarker`.
* :mod:`.checks` - checks needing the whole layout (ids, colours, dot plane, symmetry).
* :mod:`.model` - :class:`MarkerLayout`, units, metre accessors, the JSON Schema.
* :mod:`.messages` - pydantic errors turned into the user's lines.
* :mod:`.jsontext` - the written file's JSON text.
* :mod:`.files` - parse, load, save; the same layout in another dictionary.
* :mod:`.sets` - layouts used together (names, id clashes).
* :mod:`.shipped` - the layouts shipped with the package.

Typical use::

    from drovisio.layout import load_layouts, shipped_layouts_dir
    layouts = load_layouts(sorted(shipped_layouts_dir().glob("*.json")))
    corners = layouts[1].code_corners_m()   # {slot: (4, 3) float64 array in metres}
"""

from drovisio.layout.checks import DOT_COPLANAR_TOL_M, SYMMETRY_TOL_M
from drovisio.layout.dictionaries import (
    aruco_code_bits,
    aruco_dictionaries,
    aruco_dictionary_id,
    aruco_dictionary_size,
    aruco_family,
)
from drovisio.layout.errors import LayoutError
from drovisio.layout.files import (
    layout_to_json,
    load_layout,
    parse_layout,
    save_layout,
    with_dictionary,
)
from drovisio.layout.markers import UP_MIN_ANGLE_DEG, ArucoMarker, DotMarker, Marker
from drovisio.layout.model import SCHEMA_ID, UNITS_TO_M, MarkerLayout, layout_json_schema
from drovisio.layout.palette import DEFAULT_PALETTE, ColorSpec
from drovisio.layout.sets import check_id_clashes, check_layout_set, load_layouts
from drovisio.layout.shipped import (
    list_shipped_layouts,
    shipped_layout_file,
    shipped_layouts_dir,
)
from drovisio.layout.square import (
    SQUARE_ANGLE_TOL_DEG,
    SQUARE_PLANAR_REL_TOL,
    SQUARE_SIDE_REL_TOL,
    square_corners,
)

__all__ = [
    "SCHEMA_ID",
    "UNITS_TO_M",
    "DEFAULT_PALETTE",
    "SQUARE_SIDE_REL_TOL",
    "SQUARE_ANGLE_TOL_DEG",
    "SQUARE_PLANAR_REL_TOL",
    "DOT_COPLANAR_TOL_M",
    "SYMMETRY_TOL_M",
    "UP_MIN_ANGLE_DEG",
    "LayoutError",
    "ColorSpec",
    "ArucoMarker",
    "DotMarker",
    "Marker",
    "MarkerLayout",
    "aruco_dictionaries",
    "aruco_dictionary_id",
    "aruco_dictionary_size",
    "with_dictionary",
    "aruco_code_bits",
    "aruco_family",
    "square_corners",
    "parse_layout",
    "load_layout",
    "load_layouts",
    "save_layout",
    "layout_to_json",
    "check_id_clashes",
    "check_layout_set",
    "layout_json_schema",
    "shipped_layouts_dir",
    "list_shipped_layouts",
    "shipped_layout_file",
]
