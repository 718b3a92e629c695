"""The live view's map: the mission area on a scaled character grid, pure (no clock, no
console of its own), so it is tested on a capture console.

Layers, bottom to top: the users (density per cell: `·` a few, `░` many), their cluster
centres (`+`), the U2U links of the current second (`─ │ ╱ ╲`, both ways heard, as the
world's `link_mask` has them), and the UAVs by id (a lost UAV as a red `✗` and its id).
North is up. A terminal cell is about twice as tall as it is wide, so the grid has half
as many rows per metre as columns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from rich.text import Text

USERS_FEW = "·"
USERS_MANY = "░"
MANY_USERS = 4  # users in a cell from which it is drawn as "many"
CLUSTER = "+"
LOST = "✗"
CELL_ASPECT = 2.0  # a character cell's height / width
MIN_COLS, MAX_COLS = 24, 64
MIN_ROWS, MAX_ROWS = 8, 24


@dataclass(frozen=True)
class MapUav:
    id: int
    north: float
    east: float
    alive: bool = True


@dataclass(frozen=True)
class MapView:
    """What the map shows of one second: the area (metres), the users and cluster centres as
    (north, east), the UAVs, and the two-way links as pairs of UAV ids."""

    north_m: float
    east_m: float
    uavs: tuple[MapUav, ...] = ()
    users: tuple[tuple[float, float], ...] = ()
    clusters: tuple[tuple[float, float], ...] = ()
    links: tuple[tuple[int, int], ...] = field(default_factory=tuple)


def grid_size(view: MapView, max_cols: int, max_rows: int = MAX_ROWS) -> tuple[int, int]:
    """(columns, rows) for a map at most `max_cols` x `max_rows` (within MIN/MAX_COLS and
    MIN/MAX_ROWS) that keeps the area's shape."""
    max_rows = max(MIN_ROWS, min(MAX_ROWS, max_rows))
    cols = max(MIN_COLS, min(MAX_COLS, max_cols))
    rows = round(cols * view.north_m / view.east_m / CELL_ASPECT)
    if rows > max_rows:  # a tall area or a short terminal: fewer rows, and narrower to keep the shape
        rows = max_rows
        cols = max(MIN_COLS, min(cols, round(rows * CELL_ASPECT * view.east_m / view.north_m)))
    return cols, max(MIN_ROWS, rows)


def _cell(view: MapView, north: float, east: float, cols: int, rows: int) -> tuple[int, int] | None:
    if not (math.isfinite(north) and math.isfinite(east)):
        return None
    c = min(cols - 1, max(0, int(east / view.east_m * cols)))
    r = min(rows - 1, max(0, rows - 1 - int(north / view.north_m * rows)))
    return r, c


def _link_glyph(dr: int, dc: int) -> str:
    """The character of a link's slope on the grid (rows grow southwards)."""
    if abs(dc) >= 2 * abs(dr):
        return "─"
    if abs(dr) >= 2 * abs(dc):
        return "│"
    return "╱" if (dr < 0) == (dc > 0) else "╲"


def _line(a: tuple[int, int], b: tuple[int, int]) -> list[tuple[int, int]]:
    """The cells strictly between a and b (Bresenham)."""
    (r0, c0), (r1, c1) = a, b
    dr, dc = abs(r1 - r0), abs(c1 - c0)
    sr, sc = (1 if r1 > r0 else -1), (1 if c1 > c0 else -1)
    err, r, c, out = dc - dr, r0, c0, []
    while (r, c) != (r1, c1):
        e2 = 2 * err
        if e2 > -dr:
            err -= dr
            c += sc
        if e2 < dc:
            err += dc
            r += sr
        if (r, c) != (r1, c1):
            out.append((r, c))
    return out


KEY_LINES = 2
FRAME = 2  # the frame's columns (and rows)


def render_map(view: MapView, max_cols: int = 48, max_rows: int = MAX_ROWS) -> Text:
    """The map as styled text, `grid_size` cells, framed, with a two-line key below."""
    cols, rows = grid_size(view, max_cols, max_rows)
    glyph = [[" "] * cols for _ in range(rows)]
    style = [[""] * cols for _ in range(rows)]
    counts: dict[tuple[int, int], int] = {}
    for n, e in view.users:
        cell = _cell(view, n, e, cols, rows)
        if cell is not None:
            counts[cell] = counts.get(cell, 0) + 1
    for (r, c), k in counts.items():
        glyph[r][c], style[r][c] = (USERS_MANY, "grey50") if k >= MANY_USERS else (USERS_FEW, "grey50")
    for n, e in view.clusters:
        cell = _cell(view, n, e, cols, rows)
        if cell is not None:
            glyph[cell[0]][cell[1]], style[cell[0]][cell[1]] = CLUSTER, "bold cyan"
    at = {u.id: _cell(view, u.north, u.east, cols, rows) for u in view.uavs}
    for i, j in view.links:
        a, b = at.get(i), at.get(j)
        if a is None or b is None:
            continue
        ch = _link_glyph(b[0] - a[0], b[1] - a[1])
        for r, c in _line(a, b):
            glyph[r][c], style[r][c] = ch, "blue"
    for u in sorted(view.uavs, key=lambda u: u.alive):  # live UAVs on top of lost ones
        cell = at[u.id]
        if cell is None:
            continue
        label = (LOST if not u.alive else "") + str(u.id)
        c0 = min(cell[1], cols - len(label))
        for k, ch in enumerate(label):
            glyph[cell[0]][c0 + k], style[cell[0]][c0 + k] = ch, "bold red" if not u.alive else "bold green"
    out = Text()
    out.append("┌" + "─" * cols + "┐\n", style="dim")
    for r in range(rows):  # one append per run of a style: the view redraws 4 times a second
        out.append("│", style="dim")
        start = 0
        for c in range(1, cols + 1):
            if c == cols or style[r][c] != style[r][start]:
                out.append("".join(glyph[r][start:c]), style=style[r][start] or None)
                start = c
        out.append("│\n", style="dim")
    scale = view.east_m / cols
    out.append("└" + "─" * cols + "┘\n", style="dim")  # the key: two short lines, as narrow as the map
    out.append("0-9", style="bold green")
    out.append(" UAV  ")
    out.append(LOST, style="bold red")
    out.append(" lost  ")
    out.append(CLUSTER, style="bold cyan")
    out.append(" cluster\n")
    out.append(f"{USERS_FEW}{USERS_MANY}", style="grey50")
    out.append(" users  ")
    out.append("─", style="blue")
    out.append(f" link  {scale:.0f} m/col")
    return out
