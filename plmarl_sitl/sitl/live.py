"""The swarm's live status view: `render(view) -> renderable`, pure.

The launcher (and `plmarl swarm status`) fills a `SwarmView` from the world's metrics
and the agents' status messages and hands it to `render`; rich.live.Live redraws it.
With the mission known, the view carries a map (`live_map`), drawn beside the per-UAV
table when the terminal is wide enough and below it otherwise. Nothing here reads a
clock, a socket or a keyboard, so it is tested on a capture console and works over SSH
(no key input is needed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from rich.console import Console, ConsoleOptions, Group, RenderResult
from rich.segment import Segment
from rich.table import Table
from rich.text import Text

from plmarl_sitl.sitl.live_map import FRAME, KEY_LINES, MAX_COLS, MIN_COLS, MIN_ROWS, MapView, render_map

SPARK = "▁▂▃▄▅▆▇█"


@dataclass(frozen=True)
class UavView:
    id: int
    alive: bool = True
    mode: str = "?"
    armed: bool = False
    pos_ned: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    speed: float = math.nan
    neighbours: int = 0
    aoi_max: float | None = None
    last_action: tuple[float, float, float] | None = None
    link: str = "?"  # "ok", "stale", "lost" (agent status), or "dead"


@dataclass(frozen=True)
class SwarmView:
    swarm: str
    t: float
    coverage: float
    coverage_history: tuple[float, ...] = ()
    lambda2: float = math.nan
    messages_per_min: float = 0.0
    events_fired: tuple[str, ...] = ()  # "node_failure@100": the headless line
    events_named: tuple[str, ...] = ()  # "UAV 2 fails at 100 s": the view (events_fired when empty)
    speedup: float = 1.0
    uavs: tuple[UavView, ...] = field(default_factory=tuple)
    map: MapView | None = None


def sparkline(values: tuple[float, ...] | list[float], width: int = 40, lo: float = 0.0, hi: float = 1.0) -> str:
    """The last `width` values as block characters scaled to [lo, hi]."""
    vals = list(values)[-width:]
    out = []
    for v in vals:
        if v is None or math.isnan(v):
            out.append(" ")
            continue
        x = (min(max(v, lo), hi) - lo) / (hi - lo) if hi > lo else 0.0
        out.append(SPARK[min(len(SPARK) - 1, int(x * (len(SPARK) - 1) + 0.5))])
    return "".join(out)


def _fmt(x: float | None, spec: str) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    text = format(x, spec)
    return text[1:] if text.startswith("-") and float(text) == 0 else text  # no "-0"


def _link_style(link: str) -> str:
    return {"ok": "green", "stale": "yellow", "lost": "red", "dead": "bold red"}.get(link, "dim")


def render(view: SwarmView) -> Group:
    """The whole view: a swarm header and one row per UAV."""
    head = Table.grid(padding=(0, 2))
    head.add_column(justify="right", style="bold")
    head.add_column()
    head.add_row("swarm", f"{view.swarm}   t = {view.t:6.1f} s   speedup {view.speedup:g}x")
    head.add_row("coverage", Text.assemble((f"{view.coverage:5.3f} ", "bold"), (sparkline(view.coverage_history), "cyan")))
    head.add_row("lambda_2", _fmt(view.lambda2, ".2f"))
    head.add_row("signalling", f"{view.messages_per_min:.0f} msg/min")
    named = view.events_named or view.events_fired
    head.add_row("events", ", ".join(named[-3:]) if named else "none yet")

    # Fits an 80-column SSH terminal: short headers, no outer box, positions in metres,
    # speed in m/s, P-AoI in s, action = the last commanded acceleration (m/s^2, NED).
    table = Table(expand=False, header_style="bold underline", box=None, pad_edge=False, padding=(0, 1))
    for col, justify in [("UAV", "right"), ("mode", "left"), ("arm", "center"), ("N m", "right"), ("E m", "right"),
                         ("alt", "right"), ("m/s", "right"), ("nbr", "right"), ("AoI s", "right"),
                         ("action m/s2", "left"), ("link", "left")]:
        table.add_column(col, justify=justify, no_wrap=True)
    for u in view.uavs:
        n, e, d = u.pos_ned
        action = "-" if u.last_action is None else " ".join(f"{a:+.1f}" for a in u.last_action).replace("-0.0", "+0.0")
        link = "dead" if not u.alive else u.link
        table.add_row(
            str(u.id), u.mode if u.alive else "-", "yes" if u.armed else "no",
            _fmt(n, ".0f"), _fmt(e, ".0f"), _fmt(-d, ".0f"), _fmt(u.speed, ".1f"), str(u.neighbours),
            _fmt(u.aoi_max, ".0f"), action, Text(link, style=_link_style(link)),
            style=None if u.alive else "dim",
        )
    return Group(head, table if view.map is None else TableAndMap(table, view.map, head.row_count))


class TableAndMap:
    """The per-UAV table with the map beside it when the console is wide enough for both
    (the map then takes the width left, up to its largest size), else the map below. The
    map's height is fitted to the console's, less `reserved` lines above it (the header);
    stacked below a table that leaves too little room, it is left out with a note."""

    GAP = 3

    def __init__(self, table: Table, view: MapView, reserved: int) -> None:
        self.table, self.view, self.reserved = table, view, reserved

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        # The table is rendered once, to lines, and the map's lines are set beside them: a
        # grid of the two would measure and render the table again on every redraw.
        table_lines = console.render_lines(self.table, options, pad=False)
        table_w = max((Segment.get_line_length(line) for line in table_lines), default=0)
        room = options.max_width - table_w - self.GAP - FRAME
        rows_left = (options.height or options.max_height) - self.reserved - FRAME - KEY_LINES
        if room >= MIN_COLS:
            map_text = render_map(self.view, min(room, MAX_COLS), rows_left)
            map_lines = console.render_lines(map_text, options.update_width(options.max_width - table_w - self.GAP), pad=False)
            blank = Segment(" " * table_w)
            for k in range(max(len(table_lines), len(map_lines))):
                left = table_lines[k] if k < len(table_lines) else [blank]
                yield from left
                if k < len(map_lines):
                    yield Segment(" " * (table_w - Segment.get_line_length(left) + self.GAP))
                    yield from map_lines[k]
                yield Segment.line()
            return
        for line in table_lines:
            yield from line
            yield Segment.line()
        rows_left -= len(table_lines)
        if rows_left >= MIN_ROWS:
            yield render_map(self.view, options.max_width - FRAME, rows_left)
        else:
            yield Text(f"(map: a terminal {MIN_ROWS - rows_left} lines taller, or {MIN_COLS + FRAME + self.GAP + table_w} "
                       "columns wide, shows it)", style="dim")


def headless_line(view: SwarmView) -> str:
    """The one line `--headless` prints every 10 s of sim time."""
    alive = sum(u.alive for u in view.uavs)
    aoi = max((u.aoi_max for u in view.uavs if u.aoi_max is not None), default=None)
    return (
        f"t={view.t:6.1f}s coverage={view.coverage:.3f} lambda2={_fmt(view.lambda2, '.2f')} "
        f"alive={alive}/{len(view.uavs)} max_aoi={_fmt(aoi, '.0f')}s msgs/min={view.messages_per_min:.0f}"
        + (f" events={','.join(view.events_fired)}" if view.events_fired else "")
    )
