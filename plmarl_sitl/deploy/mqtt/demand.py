"""The demand message: the coarse user-density map on `plmarl/<swarm>/demand` (new in
signalling schema version 2, docs/SIGNALLING.md).

Binary, little-endian, 18 + 4K bytes: version (1), kind 'D', map_seq u16, t_ms i32 (the
mission time of the snapshot), cell_m f32, rows u16, cols u16, K u16, then K x (cell
index u16, row-major from the south-west corner; user count u16) for the nonzero cells
only, in increasing index order. `decode_demand` raises only `Malformed`, whose reason
the receiver counts (`malformed_demand_<reason>`).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from plmarl_sitl.deploy.mqtt.schema import Malformed

DEMAND_VERSION = 1
KIND_DEMAND = ord("D")
MAX_COUNT = 0xFFFF
SEQ_MOD = 1 << 16

# version, kind, map_seq, t_ms, cell_m, rows, cols, K; then K x (index, count)
_HEAD = struct.Struct("<BBHifHHH")
_CELL = struct.Struct("<HH")
HEAD_SIZE, CELL_SIZE = _HEAD.size, _CELL.size


@dataclass(frozen=True)
class DemandMsg:
    map_seq: int  # +1 per published map, modulo 2^16
    t_ms: int  # mission time of the users' snapshot (ms)
    cell_m: float  # cell side (m), as float32
    rows: int  # cells along north
    cols: int  # cells along east
    cells: tuple[tuple[int, int], ...]  # (row-major index, user count), nonzero counts, increasing index

    @property
    def t_s(self) -> float:
        return self.t_ms / 1000.0


def encode_demand(map_seq: int, t_ms: int, cell_m: float, rows: int, cols: int, counts: list[int] | object) -> bytes:
    """The message for a full row-major count vector (length rows * cols); zero cells are left out."""
    nonzero = [(i, int(c)) for i, c in enumerate(counts) if int(c)]  # type: ignore[arg-type]
    if rows * cols > SEQ_MOD or any(c > MAX_COUNT or c < 0 for _, c in nonzero):
        raise ValueError("demand map too large for the v1 message (cells < 65536, counts < 65536)")
    body = b"".join(_CELL.pack(i, c) for i, c in nonzero)
    return _HEAD.pack(DEMAND_VERSION, KIND_DEMAND, map_seq % SEQ_MOD, t_ms, cell_m, rows, cols, len(nonzero)) + body


def decode_demand(payload: bytes) -> DemandMsg:
    if len(payload) < 2:
        raise Malformed("short")
    if payload[0] != DEMAND_VERSION:
        raise Malformed("version")
    if payload[1] != KIND_DEMAND:
        raise Malformed("kind")
    if len(payload) < HEAD_SIZE:
        raise Malformed("short")
    _, _, seq, t_ms, cell_m, rows, cols, k = _HEAD.unpack_from(payload)
    if len(payload) != HEAD_SIZE + CELL_SIZE * k:
        raise Malformed("length")
    if not (math.isfinite(cell_m) and cell_m > 0.0) or rows < 1 or cols < 1 or t_ms < 0:
        raise Malformed("grid")
    cells = tuple(_CELL.iter_unpack(payload[HEAD_SIZE:]))
    last = -1
    for idx, count in cells:
        if idx <= last or idx >= rows * cols or count == 0:
            raise Malformed("cells")  # out of the grid, repeated or unordered, or a zero cell
        last = idx
    return DemandMsg(seq, t_ms, cell_m, rows, cols, cells)


def seq_newer(a: int, b: int) -> bool:
    """map_seq a is newer than b (serial-number arithmetic: the u16 wraps after 2^16 maps)."""
    return 0 < (a - b) % SEQ_MOD < SEQ_MOD // 2
