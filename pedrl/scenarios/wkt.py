"""A walkable polygon from WKT, a file or text, read under bounds: a regular file of at most :data:`MAX_WKT_BYTES`,
UTF-8 with or without a byte-order mark, at most :data:`MAX_VERTICES` vertices and :data:`MAX_WKT_NESTING` levels of
parentheses; Z (and M) coordinates are dropped with a warning.

A checkpoint holds its room: :func:`inline_geometry` turns a ``geometry`` file into the WKT text of its polygon when
training starts, and a stored scenario is read with ``files=False``, which opens no file it names.
"""

from __future__ import annotations

import os
import re
import stat
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

import numpy as np
import shapely
from shapely.geometry import Polygon

from pedrl.common.checks import shown
from pedrl.notices import warn
from pedrl.scenarios.polygons import MISSING, check_extent, check_polygon, short_reason

MAX_WKT_BYTES: Final = 10_000_000
"""Largest WKT file (bytes), or WKT text (characters), of a custom polygon: 10 MB."""
MAX_VERTICES: Final = 10_000
"""Most vertices of a custom polygon (all rings together)."""
MAX_WKT_NESTING: Final = 8
"""Most levels of parentheses in WKT (a POLYGON has 2, a GEOMETRYCOLLECTION of MULTIPOLYGONs 4)."""
_WKT_TEXT: Final = re.compile(
    r"\s*(?:MULTIPOLYGON|POLYGON|GEOMETRYCOLLECTION|MULTILINESTRING|LINESTRING|LINEARRING|MULTIPOINT|POINT)"
    r"\s*(?:ZM|Z|M)?\s*(?:\(|EMPTY\b)",
    re.IGNORECASE,
)


def geometry_file(config: Any) -> str | None:
    """The file a ``scenario`` config names as its ``geometry`` (a value that is not WKT text), else None."""
    geometry = config.get("geometry") if isinstance(config, Mapping) else None
    if geometry is None or geometry == MISSING or is_wkt_text(geometry):
        return None
    return str(geometry) if isinstance(geometry, str | os.PathLike) else None


def is_wkt_text(value: Any) -> bool:
    """``value`` is WKT text (it starts with a geometry type such as ``POLYGON (``), not the name of a file."""
    return isinstance(value, str) and _WKT_TEXT.match(value.removeprefix("\ufeff")) is not None


def inline_geometry(config: Mapping[str, Any], *, files: bool = True) -> dict[str, Any]:
    """``config`` (a ``scenario`` config) with its ``geometry``, a WKT file or WKT text, replaced by the WKT text of
    its polygon (2D, every digit kept): what a checkpoint stores, so that it holds its room instead of naming a file
    that may change or vanish. The file is read once, here, under the bounds of :func:`read_geometry`.

    Raises:
        ValueError: one line naming ``scenario.geometry``, for a file or text that is not a bounded polygon.
    """
    config = dict(config)
    geometry = config.get("geometry")
    if geometry is not None and geometry != MISSING:
        polygon = read_geometry(geometry, files=files)
        config["geometry"] = shapely.to_wkt(polygon, rounding_precision=-1, output_dimension=2)
    return config


def read_geometry(value: Any, *, key: str = "scenario.geometry", files: bool = True) -> Polygon:
    """The polygon of a ``geometry`` value: WKT text (:func:`parse_wkt`), or a WKT file (:func:`read_wkt`) unless
    ``files`` is False (a stored config, which must hold the text).

    Raises:
        ValueError: one line naming ``key`` and the value (cut to a short line), and what is allowed.
    """
    if value is None or value == MISSING:
        raise ValueError(f"{key} is missing: give a WKT file holding the walkable POLYGON, or the WKT text itself")
    if is_wkt_text(value):
        if len(value) > MAX_WKT_BYTES:
            raise ValueError(f"{key}={shown(value)} is invalid: WKT text of at most {MAX_WKT_BYTES} characters")
        return parse_wkt(value, what=f"{key}={shown(value)}")
    if not isinstance(value, str | os.PathLike) or not str(value):
        raise ValueError(f"{key}={shown(value)} is invalid: must be a WKT file or WKT text holding one POLYGON")
    if not files:
        raise ValueError(
            f"{key}={shown(str(value))} is invalid: a stored scenario holds the WKT text of its polygon, not the"
            " name of a file"
        )
    return read_wkt(value, key=key)


def read_wkt(path: str | Path, *, key: str = "scenario.geometry") -> Polygon:
    """The polygon of a WKT file (one ``POLYGON``, or a collection holding exactly one), else a one-line error.

    The file must be a regular file (a FIFO, a device or a folder is refused before anything is read) of at most
    :data:`MAX_WKT_BYTES`, UTF-8 with or without a byte-order mark; its text is checked by :func:`parse_wkt`.

    Raises:
        ValueError: one line naming ``key``, the file (cut to a short line) and what is allowed.
    """
    what = f"{key}={shown(str(path))}"
    data = _read_bounded(path, what)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise ValueError(
            f"{what} is invalid: it is not UTF-8 text (byte 0x{data[err.start]:02x} at offset {err.start}): save it as"
            " UTF-8, with or without a byte-order mark"
        ) from None
    return parse_wkt(text, what=what)


def parse_wkt(text: str, *, what: str = "scenario.geometry") -> Polygon:
    """The polygon of WKT text (one ``POLYGON``, or a collection holding exactly one), checked before it is parsed.

    At most :data:`MAX_WKT_NESTING` levels of parentheses and :data:`MAX_VERTICES` vertices (counted from the text,
    so a huge polygon is refused at once); Z and M coordinates are dropped with a warning (the footprint is used);
    the polygon must be valid and lie within :data:`MAX_COORDINATE` of the origin.

    Args:
        text: the WKT, with or without a byte-order mark.
        what: names the value in messages: the key and the file or text (``scenario.geometry='room.wkt'``).

    Raises:
        ValueError: one line starting with ``what``.
    """
    text = text.removeprefix("\ufeff").strip()
    if "\0" in text:
        raise ValueError(f"{what} is invalid: it holds a NUL character: not WKT text")
    depth = _nesting(text)
    if depth > MAX_WKT_NESTING:
        raise ValueError(
            f"{what} is invalid: its parentheses nest {depth} deep, at most {MAX_WKT_NESTING} (one POLYGON, or a"
            " collection holding one)"
        )
    vertices = text.count(",") + 1  # WKT separates vertices (and parts) with commas: at least this many
    if vertices > MAX_VERTICES:
        raise ValueError(f"{what} is invalid: it holds {vertices} vertices, at most {MAX_VERTICES}")
    try:
        with warnings.catch_warnings():  # a NaN or an overflowing number: named below, as a non-finite coordinate
            warnings.simplefilter("ignore", RuntimeWarning)
            shape = shapely.from_wkt(text)
    except (shapely.errors.GEOSException, ValueError, TypeError) as err:
        raise ValueError(f"{what} is invalid: not WKT ({short_reason(err)})") from None
    if shape is not None and (shapely.has_z(shape) or getattr(shapely, "has_m", lambda _: False)(shape)):
        warn(f"{what}: its Z coordinates are dropped: a room is 2D, its polygon's footprint is used")
        shape = shapely.force_2d(shape)
    polygons = [] if shape is None else [part for part in shapely.get_parts(shape) if isinstance(part, Polygon)]
    if len(polygons) != 1:
        raise ValueError(f"{what} is invalid: it must hold exactly one POLYGON, it holds {len(polygons)}")
    check_polygon(polygons[0], what)
    check_extent(polygons[0], what)
    return polygons[0]


def _read_bounded(path: str | Path, what: str) -> bytes:
    """The bytes of a regular file of at most :data:`MAX_WKT_BYTES`; anything else is refused without reading it."""
    try:  # O_NONBLOCK: opening a FIFO returns at once, to be refused below, instead of waiting for a writer
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except (OSError, ValueError) as err:
        raise ValueError(
            f"{what} is invalid: cannot read it ({getattr(err, 'strerror', None) or short_reason(err)})"
        ) from None
    try:
        info = os.fstat(descriptor)
        mode, size = info.st_mode, info.st_size
        if not stat.S_ISREG(mode):
            raise ValueError(f"{what} is invalid: it is {_file_kind(mode)}, not a regular file: give a WKT file")
        if size > MAX_WKT_BYTES:
            raise ValueError(f"{what} is invalid: it holds {size} bytes, at most {MAX_WKT_BYTES} (10 MB)")
        chunks, read = [], 0
        while read <= MAX_WKT_BYTES:
            chunk = os.read(descriptor, min(1 << 20, MAX_WKT_BYTES + 1 - read))
            if not chunk:
                break
            chunks.append(chunk)
            read += len(chunk)
    except OSError as err:
        raise ValueError(f"{what} is invalid: cannot read it ({err.strerror or short_reason(err)})") from None
    finally:
        os.close(descriptor)
    if read > MAX_WKT_BYTES:  # it grew while it was read
        raise ValueError(f"{what} is invalid: it holds more than {MAX_WKT_BYTES} bytes (10 MB)")
    return b"".join(chunks)


def _file_kind(mode: int) -> str:
    kinds = (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    )
    return next((kind for test, kind in kinds if test(mode)), "a special file")


def _nesting(text: str) -> int:
    """Deepest level of parentheses in ``text`` (vectorised: the text may hold 10 MB)."""
    codes = np.frombuffer(text.encode("utf-8", "replace"), dtype=np.uint8)
    steps = (codes == ord("(")).astype(np.int32) - (codes == ord(")")).astype(np.int32)
    return int(np.cumsum(steps).max(initial=0))
