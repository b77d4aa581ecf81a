"""The camera-file contract: read OpenCV FileStorage (YAML, XML, JSON) and ROS ``camera_info``
files, write them at full precision, and check every value on the way in.

Read:
    * OpenCV FileStorage YAML/XML/JSON with ``camera_matrix`` and ``distortion_coefficients``
      (as OpenCV's calibration sample writes them), optional ``image_width``/``image_height``,
      ``camera_name``, and the lens model as ``distortion_model: NAME`` or OpenCV's tutorial
      flag ``fisheye_model: 1``;
    * ROS ``camera_info`` YAML (``camera_matrix: {rows, cols, data}``, ``distortion_model``).

Every file goes through one schema, :class:`CameraFile`: finite numbers, positive focal
lengths, a principal point inside a plausible image, a capped image size, a coefficient count
that fits the named model. A model name that is not ``plumb_bob``, ``rational_polynomial``,
``fisheye`` or ``equidistant`` is refused by name. Without an image size the camera's size is
taken from the first image or the source (:meth:`drovisio.camera.Camera.for_image`).

Write: the OpenCV form by default (YAML; ``.xml``/``.json`` by suffix), ROS or OpenCV JSON on
request, through :func:`drovisio.fileio.atomic_write`, which parses the new file back and
compares it before it replaces anything.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from drovisio.camera import MODEL_ALIASES, Camera, check_coefficients, skew_problem
from drovisio.errors import LIMITS, InputError, one_line
from drovisio.fileio import atomic_write
from drovisio.textfile import BoundedYamlLoader as _BoundedYaml
from drovisio.textfile import parse_json, parse_yaml, read_text

__all__ = ["CameraFile", "CameraFileError", "CameraFormat", "NotACameraFile", "load_camera",
           "parse_opencv_yaml", "save_camera"]

CameraFormat = Literal["opencv", "ros", "json"]


class CameraFileError(InputError):
    """A camera file that cannot be used; the message names the file, the field and the fix."""


class NotACameraFile(CameraFileError):
    """A file that reads (YAML, XML or JSON) but holds none of a camera file's fields: another
    kind of file, which a reader looking through a folder for its camera file passes over."""


def _finite(v: float, what: str) -> float:
    if not math.isfinite(v):
        raise ValueError(f"{what} must be a finite number")
    return v


class CameraFile(BaseModel):
    """One camera file's content, whatever its syntax (the schema of the contract).

    Attributes:
        camera_matrix: 3×3 [[fx, s, cx], [0, fy, cy], [0, 0, 1]], pixels.
        distortion_coefficients: Coefficients of ``distortion_model``.
        distortion_model: ``plumb_bob`` (default), ``rational_polynomial``, ``fisheye`` or
            ``equidistant`` (read as ``fisheye``).
        image_width: Pixels; absent (None) when the file does not say.
        image_height: Pixels; absent (None) when the file does not say.
        camera_name: Free text.
    """

    model_config = ConfigDict(extra="ignore", allow_inf_nan=False)

    camera_matrix: list[list[float]]
    distortion_coefficients: list[float]
    distortion_model: str = "plumb_bob"
    image_width: int | None = Field(None, ge=1, le=LIMITS.max_image_side)
    image_height: int | None = Field(None, ge=1, le=LIMITS.max_image_side)
    camera_name: str = Field("camera", max_length=200)

    @field_validator("image_width", "image_height", mode="before")
    @classmethod
    def _size(cls, v: Any) -> Any:
        if isinstance(v, bool):
            raise ValueError("must be a whole number of pixels")
        if v in (0, None):   # ROS writes 0 for "not known"
            return None
        if isinstance(v, float) and v.is_integer():
            return int(v)
        if isinstance(v, str):
            try:
                return int(v.strip())
            except ValueError:
                raise ValueError(f"'{one_line(v, 40)}' is not a whole number of pixels") \
                    from None
        return v

    @field_validator("camera_matrix")
    @classmethod
    def _matrix(cls, K: list[list[float]]) -> list[list[float]]:
        if len(K) != 3 or any(len(r) != 3 for r in K):
            raise ValueError("expected a 3x3 matrix")
        for r in K:
            for x in r:
                _finite(x, "every value")
        if K[0][0] <= 0 or K[1][1] <= 0:
            raise ValueError("focal lengths fx and fy must be positive")
        if K[1][0] != 0 or K[2][0] != 0 or K[2][1] != 0 or abs(K[2][2] - 1) > 1e-9:
            raise ValueError("not a camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
        if K[0][0] > 1e6 or K[1][1] > 1e6:
            raise ValueError("focal lengths above 1e6 pixels are not a real camera")
        why = skew_problem(K[0][1], K[0][0])
        if why:
            raise ValueError(why)
        return K

    @field_validator("distortion_coefficients")
    @classmethod
    def _coefficients(cls, d: list[float]) -> list[float]:
        for x in d:
            _finite(x, "every coefficient")
            if abs(x) > 1e6:
                raise ValueError("coefficients beyond 1e6 are not a real lens")
        return d

    @field_validator("distortion_model", mode="before")
    @classmethod
    def _model(cls, v: Any) -> Any:
        if not isinstance(v, str):
            raise ValueError("must be a name: plumb_bob, rational_polynomial or fisheye")
        name = v.strip()
        if name not in MODEL_ALIASES:
            raise ValueError(f"'{one_line(name, 40)}' is not a lens model Drovisio supports; "
                             "use plumb_bob, rational_polynomial, fisheye or equidistant")
        return MODEL_ALIASES[name]

    @model_validator(mode="after")
    def _consistent(self) -> CameraFile:
        why = check_coefficients(self.distortion_model, len(self.distortion_coefficients))
        if why:
            raise ValueError(f"distortion_coefficients: {why}")
        if (self.image_width is None) != (self.image_height is None):
            raise ValueError("image_width/image_height: give both or neither")
        K = self.camera_matrix
        cx, cy = K[0][2], K[1][2]
        if self.image_width is not None:
            w, h = self.image_width, self.image_height
            if not (-0.5 <= cx <= w - 0.5 and -0.5 <= cy <= (h or 0) - 0.5):
                raise ValueError(f"camera_matrix: principal point ({cx:.6g}, {cy:.6g}) lies "
                                 f"outside the {w}x{h} image; check cx, cy and the size")
        else:
            side = LIMITS.max_image_side
            if not (0 < cx < side and 0 < cy < side):
                raise ValueError(f"camera_matrix: principal point ({cx:.6g}, {cy:.6g}) is not "
                                 "inside any image; check cx and cy")
        return self

    def to_camera(self) -> Camera:
        K = np.asarray(self.camera_matrix, np.float64)
        known = self.image_width is not None
        w = self.image_width or max(1, round(2 * K[0, 2] + 1))
        h = self.image_height or max(1, round(2 * K[1, 2] + 1))
        model = MODEL_ALIASES[self.distortion_model]
        return Camera(K=K, dist=np.asarray(self.distortion_coefficients, np.float64),
                      width=int(w), height=int(h), name=self.camera_name or "camera",
                      model=model, size_known=known)


#: pydantic's words for a type it refused, said with what to give instead
_FIXES = {
    "finite_number": "must be finite numbers (no NaN or infinity); give the calibration's "
                     "values",
    "int_parsing": "must be a whole number of pixels (the images' size)",
    "int_from_float": "must be a whole number of pixels (the images' size)",
    "int_type": "must be a whole number of pixels (the images' size)",
    "string_type": "must be text; give a name in quotes",
}


def _validated(p: Path, raw: dict[str, Any]) -> Camera:
    try:
        return CameraFile.model_validate(raw).to_camera()
    except ValidationError as e:
        err = e.errors()[0]
        loc = ".".join(str(x) for x in err["loc"] if not isinstance(x, int))
        msg = _FIXES.get(err["type"], err["msg"].removeprefix("Value error, "))
        if err["type"] in ("greater_than_equal", "less_than_equal"):
            msg = (f"{one_line(err.get('input'), 30)} pixels is not an image size; give 1 to "
                   f"{LIMITS.max_image_side}")
        if err["type"] == "missing":
            msg = "missing (a camera file needs camera_matrix and distortion_coefficients)"
        # a check of the whole file names its field at the start of its own words
        where = f"{loc}: " if loc else ""
        raise CameraFileError(f"{p}: {where}{one_line(msg, 200)}") from None


# ================================================================================ reading
def load_camera(path: str | os.PathLike) -> Camera:
    """Read an OpenCV FileStorage (YAML, XML, JSON) or ROS ``camera_info`` camera file.

    Args:
        path: The camera file.

    Returns:
        The camera. Without an image size in the file, ``size_known`` is False and the size
        comes from the first image or the source (:meth:`Camera.for_image`).

    Raises:
        CameraFileError: The file is missing, unreadable, or a field is absent or malformed;
            the message names the file and the field.
    """
    p = Path(path)
    try:
        text = read_text(p, "camera file")
    except InputError as e:
        raise CameraFileError(str(e)) from None
    head = text.lstrip()[:200]
    if head.startswith("<"):
        data = _read_opencv_xml(p, text)
    elif head.startswith("{"):
        try:
            data = parse_json(text, str(p))
        except InputError as e:
            raise CameraFileError(str(e)) from None
    else:
        data = _read_opencv_yaml(p, text)
    if not isinstance(data, dict) or not ({"camera_matrix", "distortion_coefficients",
                                           "image_width"} & set(data)):
        raise NotACameraFile(f"{p}: not a camera file: expected OpenCV FileStorage fields "
                              "'camera_matrix' and 'distortion_coefficients' or a ROS "
                              "camera_info YAML")
    return _validated(p, _from_mapping(p, data))


def _matrix_field(p: Path, data: dict, key: str, shape: tuple[int, int] | None) -> Any:
    """A ``{rows, cols, data}`` mapping (ROS, OpenCV JSON) or a plain list, as nested lists."""
    node = data.get(key)
    if node is None:
        return None
    if isinstance(node, dict):
        if "data" not in node:
            raise CameraFileError(f"{p}: {key}: expected {{rows, cols, data}}")
        values = node["data"]
        rows, cols = node.get("rows"), node.get("cols")
    else:
        values, rows, cols = node, None, None
    if isinstance(values, list) and values and all(isinstance(r, list) for r in values):
        values = [x for r in values for x in r]
    if not isinstance(values, list):
        raise CameraFileError(f"{p}: {key}.data: must be a list of numbers")
    if len(values) > 64:  # counted before any is read: the file may hold millions
        raise CameraFileError(f"{p}: {key}: " + (
            f"expected {shape[0]}x{shape[1]} values, got {len(values)}" if shape is not None
            else str(check_coefficients("plumb_bob", len(values)))))
    values = [_number(p, key, x) for x in values]
    if rows is not None or cols is not None:
        if not all(isinstance(x, int) and not isinstance(x, bool) and 0 < x <= 64
                   for x in (rows, cols)):
            raise CameraFileError(f"{p}: {key}: rows and cols must be small whole numbers")
        if int(rows) * int(cols) != len(values):  # type: ignore[arg-type]
            raise CameraFileError(f"{p}: {key}: rows x cols = {rows}x{cols} but data has "
                                  f"{len(values)} values")
    if shape is not None:
        if len(values) != shape[0] * shape[1]:
            raise CameraFileError(f"{p}: {key}: expected {shape[0]}x{shape[1]} values, got "
                                  f"{len(values)}")
        return [values[i * shape[1]:(i + 1) * shape[1]] for i in range(shape[0])]
    return values


def _number(p: Path, key: str, x: Any) -> float:
    """A number of a matrix; YAML 1.1 reads ``1e-05`` (no dot) as a string, which other
    tools write, so numeric strings are numbers too."""
    if isinstance(x, (int, float)) and not isinstance(x, bool):
        return float(x)
    if isinstance(x, str):
        try:
            return float(x)
        except ValueError:
            pass
    raise CameraFileError(f"{p}: {key}.data: '{one_line(x, 30)}' is not a number")


def _from_mapping(p: Path, data: dict[str, Any]) -> dict[str, Any]:
    """ROS ``camera_info`` YAML or OpenCV FileStorage JSON, as the schema's fields."""
    raw: dict[str, Any] = {
        "camera_matrix": _matrix_field(p, data, "camera_matrix", (3, 3)),
        "distortion_coefficients": _matrix_field(p, data, "distortion_coefficients", None),
    }
    for key in ("image_width", "image_height", "camera_name"):
        if data.get(key) is not None:
            raw[key] = data[key]
    if isinstance(raw.get("camera_name"), (int, float)):
        raw["camera_name"] = str(raw["camera_name"])
    model = _model_name(p, data.get("distortion_model"), data.get("fisheye_model"))
    if model is not None:
        raw["distortion_model"] = model
    return {k: v for k, v in raw.items() if v is not None}


def _model_name(p: Path, named: Any, fisheye_flag: Any) -> Any:
    """The lens model from ``distortion_model`` and OpenCV's ``fisheye_model`` flag."""
    if fisheye_flag in (None, 0, False):
        return named
    if fisheye_flag not in (1, True):
        raise CameraFileError(f"{p}: fisheye_model: must be 0 or 1")
    if named is not None and (not isinstance(named, str)
                              or MODEL_ALIASES.get(named.strip()) != "fisheye"):
        raise CameraFileError(f"{p}: distortion_model: '{one_line(named, 40)}' contradicts "
                              "fisheye_model: 1; keep one")
    return "fisheye"


class _OpenCVYamlLoader(_BoundedYaml):
    """OpenCV FileStorage YAML (``%YAML:1.0`` header removed): its ``!!opencv-matrix`` and
    ``!!opencv-nd-matrix`` nodes are plain mappings here."""


def _opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> Any:
    if not isinstance(node, yaml.MappingNode):
        raise yaml.constructor.ConstructorError(None, None, "an opencv-matrix must be a "
                                                "mapping of rows, cols, dt and data",
                                                node.start_mark)
    return loader.construct_mapping(node, deep=True)


for _tag in ("tag:yaml.org,2002:opencv-matrix", "tag:yaml.org,2002:opencv-nd-matrix"):
    _OpenCVYamlLoader.add_constructor(_tag, _opencv_matrix)


def parse_opencv_yaml(text: str, source: str) -> Any:
    """OpenCV FileStorage YAML text (its ``%YAML:1.0`` header, its ``!!opencv-matrix``
    nodes as mappings of rows, cols, dt and data), read by the bounded YAML reader
    (:func:`drovisio.textfile.parse_yaml`), never by OpenCV's own parser: that one aborts the
    whole process on some malformed files, blocks on a pipe and allocates whatever a
    matrix's rows and cols announce.

    Raises:
        InputError: not valid YAML, or beyond the reader's bounds; naming ``source``.
    """
    lines = text.splitlines()
    if lines and lines[0].lstrip().startswith("%YAML"):
        lines[0] = ""   # PyYAML refuses OpenCV's directive; the lines keep their numbers
    return parse_yaml("\n".join(lines), source, loader=_OpenCVYamlLoader)


def _read_opencv_yaml(p: Path, text: str) -> dict[str, Any]:
    """OpenCV FileStorage YAML (and ROS camera_info), read by :func:`parse_opencv_yaml`."""
    try:
        data = parse_opencv_yaml(text, str(p))
    except InputError as e:
        raise CameraFileError(f"{e}; expected an OpenCV or ROS camera file") from None
    if not isinstance(data, dict):
        raise NotACameraFile(f"{p}: not a camera file: expected OpenCV FileStorage fields "
                              "'camera_matrix' and 'distortion_coefficients'")
    return data


def _read_opencv_xml(p: Path, text: str) -> dict[str, Any]:
    """OpenCV FileStorage XML (``<opencv_storage>``), read by ElementTree; a document type or
    an entity (the XML bombs) is refused before parsing."""
    import xml.etree.ElementTree as ET

    if "<!DOCTYPE" in text or "<!ENTITY" in text:
        raise CameraFileError(f"{p}: XML with a DOCTYPE or entities is not a camera file")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise CameraFileError(f"{p}: not valid XML ({one_line(e, 120)})") from None
    if root.tag != "opencv_storage":
        raise NotACameraFile(f"{p}: not an OpenCV FileStorage XML file (root "
                             f"<{one_line(root.tag, 40)}>)")
    data: dict[str, Any] = {}
    for child in list(root)[:64]:
        if len(child):                       # a matrix: rows, cols, dt, data
            m = {sub.tag: (sub.text or "").strip() for sub in child}
            entry: dict[str, Any] = {"data": m.get("data", "").split()}
            for k in ("rows", "cols"):
                if k in m:
                    try:
                        entry[k] = int(m[k])
                    except ValueError:
                        raise CameraFileError(f"{p}: {child.tag}.{k}: '{one_line(m[k], 20)}' "
                                              "is not a whole number") from None
            data[child.tag] = entry
        else:
            value = (child.text or "").strip()
            try:
                data[child.tag] = int(value)
            except ValueError:
                try:
                    data[child.tag] = float(value)
                except ValueError:
                    data[child.tag] = value.strip('"')
    return data


# ================================================================================ writing
def _fmt_float(x: float) -> str:
    """The shortest string that round-trips a double exactly, with a dot before any exponent
    (YAML 1.1 reads ``1e-05`` as a string)."""
    s = repr(float(x))
    if "e" in s and "." not in s:
        mant, _, exp = s.partition("e")
        s = f"{mant}.0e{exp}"
    return s


def save_camera(camera: Camera, path: str | os.PathLike, fmt: CameraFormat | None = None
                ) -> Path:
    """Write a camera file atomically, at full precision, checked by reading it back.

    Args:
        camera: The camera.
        path: Destination. Its suffix picks the form when ``fmt`` is None: ``.json`` → OpenCV
            JSON, ``.xml`` → OpenCV XML, anything else → OpenCV YAML.
        fmt: ``"opencv"`` (FileStorage YAML/XML by suffix), ``"ros"`` (camera_info YAML) or
            ``"json"`` (OpenCV FileStorage JSON).

    Returns:
        The path written.

    Raises:
        drovisio.errors.WriteError: Not written (full disk, no permission, or the file read
            back differs); any previous file is untouched.
    """
    p = Path(path)
    if fmt is None:
        fmt = "json" if p.suffix.lower() == ".json" else "opencv"
    if fmt not in ("opencv", "ros", "json"):
        raise ValueError(f"unknown camera file format {fmt!r}; use opencv, ros or json")

    def verify(tmp: Path) -> None:
        back = load_camera(tmp)
        if not back.almost_equal(camera):
            raise ValueError("the camera read back differs from the one written")

    if fmt == "ros":
        def write(tmp: Path) -> None:
            tmp.write_text(_ros_text(camera), encoding="utf-8")
        atomic_write(p, write, suffix=".yaml", make_parents=True, verify=verify)
        return p

    suffix = ".json" if fmt == "json" else (".xml" if p.suffix.lower() == ".xml" else ".yaml")

    def write_fs(tmp: Path) -> None:
        # FileStorage picks its syntax from the suffix: write beside it under that suffix
        real = tmp.with_suffix(suffix)
        fs = cv2.FileStorage(str(real), cv2.FILE_STORAGE_WRITE)
        try:
            if camera.size_known:
                fs.write("image_width", camera.width)
                fs.write("image_height", camera.height)
            fs.write("camera_name", camera.name)
            fs.write("distortion_model", camera.model)
            fs.write("camera_matrix", camera.K)
            fs.write("distortion_coefficients", camera.dist.reshape(1, -1))
        finally:
            fs.release()
        if real != tmp:
            os.replace(real, tmp)

    atomic_write(p, write_fs, suffix=suffix, make_parents=True, verify=verify)
    return p


def _ros_text(camera: Camera) -> str:
    K = camera.K
    P = np.zeros((3, 4))
    P[:3, :3] = K
    model = "equidistant" if camera.is_fisheye else camera.model

    def block(name: str, rows: int, cols: int, values: np.ndarray) -> str:
        vals = ", ".join(_fmt_float(v) for v in np.ravel(values))
        return f"{name}:\n  rows: {rows}\n  cols: {cols}\n  data: [{vals}]\n"

    size = (f"image_width: {camera.width}\nimage_height: {camera.height}\n"
            if camera.size_known else "")
    return (size + f"camera_name: {json.dumps(camera.name)}\n"
            + block("camera_matrix", 3, 3, K)
            + f"distortion_model: {model}\n"
            + block("distortion_coefficients", 1, camera.dist.size, camera.dist)
            + block("rectification_matrix", 3, 3, np.eye(3))
            + block("projection_matrix", 3, 4, P))
