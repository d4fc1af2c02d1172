"""Where the robot has looked: a grid of floor cells with a probability of detection.

Each cell (``cell_m`` square, 0.25 m by default) of the local NED floor holds the
probability that a lying adult in it would have been found by the looks so far.
Looks combine as independent chances:

    p_cell = 1 - prod_i (1 - p_i)

so the grid keeps ``miss = prod_i (1 - p_i)`` per cell (1 = never looked at) and a
look multiplies it by ``1 - p``: a cell's probability stays in [0, 1] and never falls.
What a look's ``p`` is (the detector's chance at that range and light) is the
caller's (companion/coverage.py); this module is the arithmetic and its saved forms.

Cells are addressed by integer indices on the whole floor, ``(floor(north_m /
cell_m), floor(east_m / cell_m))``; the array covers the bounding box of the cells
looked at and grows (in steps of ``_GROW_CELLS``) as the robot goes on. It never
grows beyond ``max_side_cells`` cells along either axis (1600 by default: 400 m at
0.25 m, 10 MB at most): a look's cells outside that window are not recorded, and
``cells_refused`` counts them, so the map never claims them.

A look that moves a cell to another *level* (0: never looked at; then one level per
tenth of probability, so the first look, "glanced at" at 0.3 and "searched well" at
0.9 always do) stamps the cell with a new ``version``; ``delta_since(v)`` gives the
cells stamped after ``v`` with their quantised p (``p_q``: 0..255, p = p_q / 255;
compact, for the radio), and ``apply_delta`` sets those cells on another grid, which
then holds every cell at the sender's level, never above the sender's p and less
than a tenth below it. Stamping each change of p_q instead sent three times the
bytes (bench/coverage.py) for differences no one reads off a map. ``snapshot`` / ``restore`` are a JSON-able dict (for SQLite); a
snapshot that is not one this module wrote is refused with a ``CoverageError``
naming what is wrong.
"""

from __future__ import annotations

import base64
import math
import struct
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.errors import FusionError

CellIndex = NDArray[np.int64]  # (K, 2): north index, east index

SNAPSHOT_FORMAT = "rescue-coverage"
SNAPSHOT_VERSION = 2
_MISS_SCALE = 65535  # a snapshot keeps prod(1 - p) to 1/65535, rounded down
SEARCHED_WELL_P = 0.9  # "searched well": a person there would have been found, 9 in 10
GLANCED_AT_P = 0.3  # "glanced at"
_GROW_CELLS = 32  # the array grows by at least this many cells on a side
_Q_MAX = 255
_DELTA_HEADER = struct.Struct("<4sIIfI")  # magic, from version, to version, cell_m, count
_DELTA_MAGIC = b"RCD1"


class CoverageError(FusionError, ValueError):
    """A coverage snapshot, delta or argument that cannot be used; says what is wrong."""


def quantise(p: NDArray[np.float64]) -> NDArray[np.uint8]:
    """Probabilities as 0..255, rounded down (a quantised grid never claims more),
    within 1e-4 of a step (float32 cells: a received q / 255 reads back as q); a cell
    looked at is at least 1, so it never reads as never looked at."""
    p = np.clip(np.asarray(p, float), 0.0, 1.0)
    q = np.floor(p * _Q_MAX + 1e-4)
    return np.where(p > 0.0, np.maximum(q, 1.0), 0.0).astype(np.uint8)


def level(p: NDArray[np.float64]) -> NDArray[np.int64]:
    """0 for a cell never looked at, else 1 + the tenths of its quantised probability
    (1..11): the same on a sender and on a receiver of its deltas."""
    q = quantise(p).astype(np.int64)
    return np.where(q > 0, 1 + (q * 10) // _Q_MAX, 0)


@dataclass(frozen=True)
class CoverageDelta:
    """The cells changed between two versions: global cell indices (K, 2) and their
    quantised probability (K,) at ``to_version``."""

    from_version: int
    to_version: int
    cell_m: float
    cells: CellIndex
    p_q: NDArray[np.uint8]

    def __len__(self) -> int:
        return len(self.p_q)

    def encode(self) -> bytes:
        """Little-endian bytes: a 20-byte header, then per cell int16 north index,
        int16 east index and uint8 p_q (5 bytes a cell)."""
        if len(self.cells) and int(np.abs(self.cells).max()) > 32767:
            raise CoverageError("a cell index does not fit 16 bits (over 8 km from the origin)")
        rows = np.empty(len(self.p_q), dtype=[("n", "<i2"), ("e", "<i2"), ("q", "u1")])
        rows["n"], rows["e"], rows["q"] = self.cells[:, 0], self.cells[:, 1], self.p_q
        header = _DELTA_HEADER.pack(
            _DELTA_MAGIC, self.from_version, self.to_version, self.cell_m, len(rows)
        )
        return header + rows.tobytes()

    @classmethod
    def decode(cls, data: bytes) -> CoverageDelta:
        if len(data) < _DELTA_HEADER.size:
            raise CoverageError(f"coverage delta: {len(data)} bytes, shorter than its header")
        magic, v0, v1, cell_m, count = _DELTA_HEADER.unpack_from(data)
        if magic != _DELTA_MAGIC:
            raise CoverageError(f"coverage delta: starts with {magic!r}, not {_DELTA_MAGIC!r}")
        if len(data) != _DELTA_HEADER.size + 5 * count:
            raise CoverageError(
                f"coverage delta: {len(data)} bytes, expected {_DELTA_HEADER.size + 5 * count} "
                f"for {count} cells"
            )
        _check_cell_m(float(cell_m))
        rows = np.frombuffer(
            data, dtype=[("n", "<i2"), ("e", "<i2"), ("q", "u1")], offset=_DELTA_HEADER.size
        )
        cells = np.column_stack([rows["n"], rows["e"]]).astype(np.int64).reshape(-1, 2)
        return cls(v0, v1, float(cell_m), cells, rows["q"].copy())


@dataclass(frozen=True)
class CoverageSummary:
    """Areas by how well they were searched, over ``area_m2`` (the extent asked for,
    or the grid's bounding box)."""

    area_m2: float
    searched_well_m2: float  # p >= SEARCHED_WELL_P
    glanced_at_m2: float  # p >= GLANCED_AT_P (includes the searched well)
    looked_at_m2: float  # p > 0

    @property
    def searched_well_share(self) -> float:
        return self.searched_well_m2 / self.area_m2 if self.area_m2 > 0 else 0.0

    @property
    def glanced_at_share(self) -> float:
        return self.glanced_at_m2 / self.area_m2 if self.area_m2 > 0 else 0.0


def _check_cell_m(cell_m: float) -> None:
    if not (math.isfinite(cell_m) and 0.05 <= cell_m <= 10.0):
        raise CoverageError(f"cell_m = {cell_m!r}: must be a size in [0.05, 10] m")


class CoverageGrid:
    """The accumulated probability of detection per floor cell. Owned by one thread."""

    def __init__(self, cell_m: float = 0.25, max_side_cells: int = 1600) -> None:
        _check_cell_m(cell_m)
        if not 16 <= max_side_cells <= 16384:
            raise CoverageError(f"max_side_cells = {max_side_cells!r}: must be in [16, 16384]")
        self.cell_m = float(cell_m)
        self.max_side_cells = int(max_side_cells)
        self.version = 0  # increases with every look that changed a cell's level
        self.looks = 0
        self.cells_refused = 0  # cells of looks outside the largest window
        self._origin = np.zeros(2, np.int64)  # global index of array cell (0, 0)
        self._miss = np.ones((0, 0), np.float32)  # prod (1 - p) per cell
        self._stamp = np.zeros((0, 0), np.uint32)  # version of the last change of level

    # -- geometry ------------------------------------------------------------------------

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self._miss.shape[0]), int(self._miss.shape[1]))

    @property
    def origin_index(self) -> tuple[int, int]:
        """The global cell index of the array's first cell (north, east)."""
        return (int(self._origin[0]), int(self._origin[1]))

    def extent_ne_m(self) -> tuple[float, float, float, float]:
        """(north0, north1, east0, east1) of the array's cells, metres."""
        (r, c), (n0, e0) = self.shape, self.origin_index
        s = self.cell_m
        return (n0 * s, (n0 + r) * s, e0 * s, (e0 + c) * s)

    def cell_of(self, north_m: NDArray[np.float64], east_m: NDArray[np.float64]) -> CellIndex:
        """Global cell indices (K, 2) of floor points."""
        n = np.floor(np.asarray(north_m, float) / self.cell_m)
        e = np.floor(np.asarray(east_m, float) / self.cell_m)
        return np.column_stack([n.ravel(), e.ravel()]).astype(np.int64)

    def centres_ne_m(self, cells: CellIndex) -> NDArray[np.float64]:
        """Floor points (K, 2) at the centres of cells."""
        return (np.asarray(cells, float) + 0.5) * self.cell_m

    def _fit(self, cells: CellIndex) -> NDArray[np.bool_]:
        """Grow the array to hold ``cells`` as far as the window allows; a mask of the
        cells it now holds."""
        if len(cells) == 0:
            return np.zeros(0, bool)
        lo, hi = cells.min(axis=0), cells.max(axis=0) + 1
        rows, origin = self.shape[0], self._origin
        size = np.array(self.shape, np.int64)
        if rows:
            lo = np.minimum(lo, origin)
            hi = np.maximum(hi, origin + size)
        if rows == 0 or (lo < origin).any() or (hi > origin + size).any():
            self._grow(lo, hi)
        end = self._origin + np.array(self.shape, np.int64)
        inside = np.asarray(((cells >= self._origin) & (cells < end)).all(axis=1), bool)
        return inside

    def _grow(self, lo: CellIndex, hi: CellIndex) -> None:
        rows, cols = self.shape
        old_lo = self._origin.copy()
        old_hi = old_lo + np.array(self.shape, np.int64)
        new_lo = np.where(lo < old_lo, lo - _GROW_CELLS, old_lo) if rows else lo - _GROW_CELLS
        new_hi = np.where(hi > old_hi, hi + _GROW_CELLS, old_hi) if rows else hi + _GROW_CELLS
        # Never wider than the window: keep what is already held, then the side the
        # new cells lie on, as far as the window reaches.
        for axis in (0, 1):
            if new_hi[axis] - new_lo[axis] > self.max_side_cells:
                if rows:
                    room = self.max_side_cells - (old_hi[axis] - old_lo[axis])
                    grow_lo = max(0, min(room, old_lo[axis] - lo[axis]))
                    new_lo[axis] = old_lo[axis] - grow_lo
                    new_hi[axis] = min(new_hi[axis], new_lo[axis] + self.max_side_cells)
                else:
                    new_hi[axis] = new_lo[axis] + self.max_side_cells
        shape = (int(new_hi[0] - new_lo[0]), int(new_hi[1] - new_lo[1]))
        miss = np.ones(shape, np.float32)
        stamp = np.zeros(shape, np.uint32)
        if rows:
            r0, c0 = old_lo - new_lo
            miss[r0 : r0 + rows, c0 : c0 + cols] = self._miss
            stamp[r0 : r0 + rows, c0 : c0 + cols] = self._stamp
        self._origin, self._miss, self._stamp = new_lo.astype(np.int64), miss, stamp

    # -- looks -----------------------------------------------------------------------------

    def add_look(self, cells: CellIndex, p: NDArray[np.float64]) -> int:
        """One look: cell (K, 2) had chance p (K,) of finding a person there. A cell
        listed twice takes its largest p once. Returns the cells recorded."""
        cells = np.asarray(cells, np.int64).reshape(-1, 2)
        p = np.asarray(p, float).ravel()
        if len(p) != len(cells):
            raise CoverageError(f"add_look: {len(cells)} cells but {len(p)} probabilities")
        if not np.all((p >= 0.0) & (p <= 1.0)):  # also refuses nan
            raise CoverageError("add_look: a probability is not in [0, 1]")
        keep = p > 0.0
        cells, p = cells[keep], p[keep]
        inside = self._fit(cells)
        self.cells_refused += int((~inside).sum())
        cells, p = cells[inside], p[inside]
        if len(p) == 0:
            return 0
        self.looks += 1
        rc = cells - self._origin
        flat = rc[:, 0] * self.shape[1] + rc[:, 1]
        order = np.lexsort((-p, flat))  # by cell, the largest p first
        flat, p = flat[order], p[order]
        first = np.ones(len(flat), bool)
        first[1:] = flat[1:] != flat[:-1]
        flat, p = flat[first], p[first]
        miss = self._miss.reshape(-1)
        before = level(1.0 - miss[flat].astype(float))
        miss[flat] = (miss[flat] * (1.0 - p)).astype(np.float32)
        changed = flat[level(1.0 - miss[flat].astype(float)) != before]
        if len(changed):
            self.version += 1
            self._stamp.reshape(-1)[changed] = self.version
        return len(flat)

    # -- reading -----------------------------------------------------------------------

    def probabilities(self) -> NDArray[np.float64]:
        """p per array cell (rows north from the origin, columns east)."""
        return 1.0 - self._miss.astype(float)

    def p_at(self, cells: CellIndex) -> NDArray[np.float64]:
        """p of global cells (K, 2); 0 outside the array."""
        cells = np.asarray(cells, np.int64).reshape(-1, 2)
        rc = cells - self._origin
        ok = ((rc >= 0) & (rc < np.array(self.shape, np.int64))).all(axis=1)
        out = np.zeros(len(cells))
        out[ok] = 1.0 - self._miss[rc[ok, 0], rc[ok, 1]].astype(float)
        return out

    def summary(
        self, extent_ne_m: tuple[float, float, float, float] | None = None
    ) -> CoverageSummary:
        """Areas searched well, glanced at and looked at, over ``extent_ne_m`` (n0, n1,
        e0, e1: the cells whose centres lie in it) or over the grid's bounding box."""
        p = self.probabilities()
        a = self.cell_m**2
        if extent_ne_m is None:
            area = p.size * a
        else:
            n0, n1, e0, e1 = extent_ne_m
            cn = (self._origin[0] + np.arange(p.shape[0]) + 0.5) * self.cell_m
            ce = (self._origin[1] + np.arange(p.shape[1]) + 0.5) * self.cell_m
            p = p[((cn >= n0) & (cn < n1))][:, ((ce >= e0) & (ce < e1))]
            area = max(0.0, n1 - n0) * max(0.0, e1 - e0)
        return CoverageSummary(
            area_m2=float(area),
            searched_well_m2=float((p >= SEARCHED_WELL_P).sum() * a),
            glanced_at_m2=float((p >= GLANCED_AT_P).sum() * a),
            looked_at_m2=float((p > 0.0).sum() * a),
        )

    # -- deltas ------------------------------------------------------------------------

    def delta_since(self, version: int) -> CoverageDelta:
        """The cells whose level changed after ``version``, with their p_q now."""
        rows, cols = np.nonzero(self._stamp > version)
        cells = np.column_stack([rows, cols]).astype(np.int64) + self._origin
        p_q = quantise(1.0 - self._miss[rows, cols].astype(float))
        return CoverageDelta(int(version), self.version, self.cell_m, cells, p_q)

    def quantised(self) -> NDArray[np.uint8]:
        """p_q per array cell (what a receiver of every delta holds)."""
        return quantise(self.probabilities())

    def apply_delta(self, delta: CoverageDelta) -> None:
        """Set the delta's cells to its quantised probabilities (a receiver's grid: it
        then holds the sender's levels). A cell never falls: a delta that
        arrives late does not undo a newer one."""
        if delta.cell_m != self.cell_m:
            raise CoverageError(f"delta of {delta.cell_m} m cells on a grid of {self.cell_m} m")
        inside = self._fit(delta.cells)
        self.cells_refused += int((~inside).sum())
        rc = delta.cells[inside] - self._origin
        p = delta.p_q[inside].astype(float) / _Q_MAX
        current = 1.0 - self._miss[rc[:, 0], rc[:, 1]].astype(float)
        self._miss[rc[:, 0], rc[:, 1]] = (1.0 - np.maximum(current, p)).astype(np.float32)
        self.version = max(self.version, delta.to_version)

    # -- saved form ----------------------------------------------------------------------

    def _miss_u16(self) -> NDArray[np.uint16]:
        """prod(1 - p) per cell in 1/65535 steps, rounded down (a restored cell never
        claims less, and one looked at stays so; float32 q / 65535 reads back as q)."""
        miss = self._miss.astype(np.float64)
        q = np.floor(miss * _MISS_SCALE + 0.01)
        # A cell looked at stays looked at, however small its p.
        return np.where(miss < 1.0, np.minimum(q, _MISS_SCALE - 1), _MISS_SCALE).astype("<u2")

    def snapshot(self) -> dict[str, Any]:
        """A JSON-able dict of the whole grid (zlib-compressed arrays in base64): the
        cells' prod(1 - p) to 1/65535 (float32's random low bits do not compress: a
        66 m square of random cells took 90 ms and 300 kB as float32, 14 ms and 140 kB so)."""
        return {
            "format": SNAPSHOT_FORMAT,
            "version": SNAPSHOT_VERSION,
            "cell_m": self.cell_m,
            "max_side_cells": self.max_side_cells,
            "origin": [int(self._origin[0]), int(self._origin[1])],
            "shape": list(self.shape),
            "grid_version": self.version,
            "looks": self.looks,
            "cells_refused": self.cells_refused,
            "miss": _pack(self._miss_u16()),
            "stamp": _pack(self._stamp.astype("<u4")),
        }

    @classmethod
    def restore(cls, snap: Any) -> CoverageGrid:
        """The grid a snapshot describes; CoverageError naming the first bad field."""
        if not isinstance(snap, dict):
            raise CoverageError(f"coverage snapshot: a {type(snap).__name__}, not a table")
        if snap.get("format") != SNAPSHOT_FORMAT or snap.get("version") != SNAPSHOT_VERSION:
            raise CoverageError(
                f"coverage snapshot: format {snap.get('format')!r} version "
                f"{snap.get('version')!r}, expected {SNAPSHOT_FORMAT!r} {SNAPSHOT_VERSION}"
            )
        cell_m = _number(snap, "cell_m")
        grid = cls(cell_m, _count(snap, "max_side_cells"))
        origin = _pair(snap, "origin", 2**31)
        shape = _pair(snap, "shape", grid.max_side_cells + 1)
        if min(shape) < 0 or (shape[0] == 0) != (shape[1] == 0):
            raise CoverageError(f"coverage snapshot: shape {shape}: not two sizes")
        miss = _unpack(snap, "miss", "<u2", shape).astype(np.float64) / _MISS_SCALE
        stamp = _unpack(snap, "stamp", "<u4", shape)
        grid.version = _count(snap, "grid_version")
        if stamp.size and int(stamp.max()) > grid.version:
            raise CoverageError("coverage snapshot: a cell's stamp is newer than grid_version")
        grid.looks = _count(snap, "looks")
        grid.cells_refused = _count(snap, "cells_refused")
        grid._origin = np.array(origin, np.int64)
        grid._miss = miss.astype(np.float32)
        grid._stamp = stamp.astype(np.uint32)
        return grid


def _pack(a: NDArray[Any]) -> str:
    return base64.b64encode(zlib.compress(a.tobytes(), 1)).decode("ascii")


def _unpack(snap: dict[str, Any], key: str, dtype: str, shape: list[int]) -> NDArray[Any]:
    text = snap.get(key)
    if not isinstance(text, str):
        raise CoverageError(f"coverage snapshot: {key} is not text")
    try:
        raw = zlib.decompress(base64.b64decode(text.encode("ascii"), validate=True))
    except (ValueError, zlib.error, UnicodeEncodeError) as exc:
        raise CoverageError(f"coverage snapshot: {key} is not compressed base64 ({exc})") from None
    size = np.dtype(dtype).itemsize
    if len(raw) != shape[0] * shape[1] * size:
        raise CoverageError(
            f"coverage snapshot: {key} holds {len(raw)} bytes, expected "
            f"{shape[0] * shape[1] * size} for shape {shape}"
        )
    return np.frombuffer(raw, dtype=dtype).reshape(shape)


def _pair(snap: dict[str, Any], key: str, bound: int) -> list[int]:
    value = snap.get(key)
    if (
        isinstance(value, list)
        and len(value) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) and abs(v) < bound for v in value)
    ):
        return [int(v) for v in value]
    raise CoverageError(
        f"coverage snapshot: {key} {str(value)[:40]}: not two integers under {bound}"
    )


def _number(snap: dict[str, Any], key: str) -> float:
    value = snap.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise CoverageError(f"coverage snapshot: {key} = {str(value)[:40]!r}: not a number")
    _check_cell_m(float(value))
    return float(value)


def _count(snap: dict[str, Any], key: str) -> int:
    value = snap.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2**32:
        raise CoverageError(f"coverage snapshot: {key} = {str(value)[:40]!r}: not a count")
    return value
