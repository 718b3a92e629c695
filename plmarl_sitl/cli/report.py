"""`plmarl report DIR`: plots and summary of a recorded swarm run."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report",
        help="draw the plots of a recorded run and print its summary",
        description="Read a run directory written by `plmarl swarm up --out DIR` (metrics.jsonl, "
        "events.jsonl, summary.json) and write coverage.png (events marked), aoi.png (max P-AoI per "
        "UAV) and trajectories.png into it, then print the summary.",
        epilog="example:\n  plmarl report runs/2026-11-21T15-00-00",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("run_dir", type=Path, help="the run directory")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from plmarl_sitl.sitl.report import draw, load_run
    from plmarl_sitl.sitl.summary import summarize

    metrics, events, summary = load_run(args.run_dir)
    if summary is None:
        summary = summarize(metrics, events, speedup=float("nan"))
    pngs = draw(args.run_dir, metrics, events)
    if args.json:
        print(json.dumps(summary))
        return 0
    from rich.console import Console

    from plmarl_sitl.sitl.report import print_summary

    console = Console()
    print_summary(summary, console, title=f"run {args.run_dir}")
    for p in pngs:
        console.print(f"wrote {p}")
    return 0
