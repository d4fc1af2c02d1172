"""The searched-area map on the radio: RESCUE_COVERAGE pieces, without I/O.

A delta of the robot's coverage grid (``fusion.coverage.CoverageDelta``: the cells
whose level changed since the version the HQ acknowledged) is cut into pieces of at
most ``CELLS_PER_PIECE`` cells, each encoded as a delta of its own (same from and to
version) in one RESCUE_COVERAGE: 20 + 15 x 5 = 95 bytes of its 98. A signed piece
then fills a TUNNEL exactly as a picture chunk does (103 bytes of payload).

Each piece is complete in itself: the receiver sets each cell to the larger of what it
holds and what the piece says (``CoverageGrid.apply_delta``), so pieces may come in
any order, twice, or late. The robot numbers each piece (``seq``) and resends it until
a RESCUE_ACK names that number; when every piece of a delta is acknowledged the HQ
holds the robot's map up to the delta's ``to_version``.

``BadPiece`` (a ValueError) names what is wrong with a piece that cannot be used.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np

from fusion.coverage import CoverageDelta, CoverageError
from mavlink_io.errors import MavlinkIOError

DATA_BYTES = 98
CELLS_PER_PIECE = 15  # 20-byte header + 15 x 5 bytes = 95 <= DATA_BYTES
PIECE_HEADER_BYTES = 20
MAX_SEQ = 0xFFFFFFFF


class BadPiece(MavlinkIOError, ValueError):
    """A RESCUE_COVERAGE that cannot be used; the text says why."""


def pieces(delta: CoverageDelta) -> list[CoverageDelta]:
    """``delta`` as pieces of at most CELLS_PER_PIECE cells (none for an empty one)."""
    return [
        CoverageDelta(
            delta.from_version,
            delta.to_version,
            delta.cell_m,
            delta.cells[i : i + CELLS_PER_PIECE],
            delta.p_q[i : i + CELLS_PER_PIECE],
        )
        for i in range(0, len(delta), CELLS_PER_PIECE)
    ]


def piece_msg(module: ModuleType, seq: int, piece: CoverageDelta) -> Any:
    """The RESCUE_COVERAGE that carries ``piece`` (ValueError when it is too big)."""
    data = piece.encode()
    if len(data) > DATA_BYTES:
        raise ValueError(f"a piece of {len(piece)} cells takes {len(data)} > {DATA_BYTES} bytes")
    return module.MAVLink_rescue_coverage_message(
        seq, len(data), list(data) + [0] * (DATA_BYTES - len(data))
    )


def piece_bytes(piece: CoverageDelta) -> int:
    """The bytes of ``piece`` in its message's data."""
    return PIECE_HEADER_BYTES + 5 * len(piece)


def piece_from_msg(msg: Any) -> CoverageDelta:
    """The checked piece in a RESCUE_COVERAGE; BadPiece names what is wrong."""
    length = int(msg.length)
    if not PIECE_HEADER_BYTES <= length <= DATA_BYTES:
        raise BadPiece(f"length {length} is not in {PIECE_HEADER_BYTES}..{DATA_BYTES}")
    try:
        piece = CoverageDelta.decode(bytes(msg.data[:length]))
    except CoverageError as exc:
        raise BadPiece(str(exc)) from None
    if piece.from_version > piece.to_version:
        raise BadPiece(
            f"from version {piece.from_version} is after its to version {piece.to_version}"
        )
    if len(piece) and not np.all(piece.p_q > 0):
        raise BadPiece("a cell says 0 (never looked at): a piece holds only cells looked at")
    return piece
