"""`plmarl report DIR`: plots, CSV, HTML and summary of a recorded swarm run."""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

from plmarl_sitl.config import PROJECT_POLICIES
from plmarl_sitl.errors import PlmarlError

TWIN_CACHE = "twin_coverage.json"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report",
        help="draw the plots of a recorded run, write its CSV (and HTML) and print its summary",
        description="Read a run directory written by `plmarl swarm up --out DIR` (metrics.jsonl, "
        "events.jsonl, mission.yaml, summary.json) and write into it: coverage.png (coverage and lambda_2 "
        "over time, every event named, and the twin's coverage on the same mission, seed and policy as a "
        "reference), aoi.png (max P-AoI per UAV and second, a heat map), trajectories.png (tracks, users "
        "and clusters, launch line, lost UAVs, links over time) and metrics.csv (one row per second: t, "
        "coverage, lambda2, messages, alive, then uavI_alive/north/east/alt/speed/aoi_max per UAV); "
        "then print the summary. A failure counts as re-stabilised only when coverage comes back within "
        "max(0.02, 5 %) of its level over the 10 s before it and stays there >= 10 s.",
        epilog="examples:\n  plmarl report runs/2026-11-21T15-00-00\n"
        "  plmarl report runs/failure --html      # also report.html, one self-contained file\n"
        "  plmarl report runs/failure --no-twin   # skip the twin's reference run",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("run_dir", type=Path, help="the run directory")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--html", action="store_true", help="also write report.html: summary, events and plots in one file")
    p.add_argument("--no-twin", action="store_true",
                   help="no twin reference on coverage.png (the twin's run takes a few seconds; it is cached in "
                   f"RUN_DIR/{TWIN_CACHE})")
    p.add_argument("--policy", type=Path, default=None,
                   help="the policy the twin flies (default: the run's, as summary.json records it; else "
                   "policies/pl-marl)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from plmarl_sitl.sitl.report import draw, load_run
    from plmarl_sitl.sitl.report_csv import write_metrics_csv
    from plmarl_sitl.sitl.summary import summarize

    metrics, events, summary = load_run(args.run_dir)
    fresh = summarize(metrics, events, speedup=float("nan"))
    if summary is None:
        summary = fresh
    else:  # the failure records of the current definitions, also for a run recorded before them
        summary["node_failures"] = fresh["node_failures"]
    notes: list[str] = []
    twin = None if args.no_twin else twin_reference(args.run_dir, summary, args.policy, notes)
    pngs = draw(args.run_dir, metrics, events, summary, twin)
    written = [*pngs, write_metrics_csv(args.run_dir / "metrics.csv", metrics)]
    if args.html:
        from plmarl_sitl.sitl.report_html import write_html
        from plmarl_sitl.sitl.report_map import run_mission

        mission = run_mission(args.run_dir)
        head = [f"mission {mission.name}, N = {mission.n_uavs} (the run's mission.yaml)"] if mission is not None else []
        if twin:
            head += [f"reference on coverage.png: {twin['label']}"] + ([twin["note"]] if twin["note"] else [])
        written.append(write_html(args.run_dir / "report.html", f"plmarl run {args.run_dir.name}", summary, events, pngs,
                                  head + notes))
    if args.json:
        print(json.dumps(summary))
        return 0
    from rich.console import Console

    from plmarl_sitl.sitl.report import print_summary

    console = Console()
    print_summary(summary, console, title=f"run {args.run_dir}")
    if twin:
        tc = twin["coverage"][: len(metrics) - 1]  # the twin's C(1..T) beside the run's seconds 1..T
        console.print(f"reference: {twin['label']}: mean coverage {sum(tc) / max(1, len(tc)):.3f} over t = 1..{len(tc)} "
                      f"(this run {sum(r['coverage'] for r in metrics[1:len(tc) + 1]) / max(1, len(tc)):.3f})", highlight=False)
    for note in notes:
        console.print(note, highlight=False)
    for p in written:
        console.print(f"wrote {p}", highlight=False)
    return 0


def twin_reference(run_dir: Path, summary: dict, policy: Path | None, notes: list[str]) -> dict | None:
    """The twin's coverage on the run's mission (mission.yaml: events included), seed and
    policy, cached in RUN_DIR/twin_coverage.json; None (and a note why) when it cannot be
    run. The label says what the line is."""
    mission_file = run_dir / "mission.yaml"
    if not mission_file.exists():
        notes.append("no twin reference: the run directory has no mission.yaml")
        return None
    recorded = summary.get("policy")
    policy_dir = policy or (Path(recorded) if recorded else PROJECT_POLICIES / "pl-marl")
    seed = summary.get("seed")
    key = {"mission_sha256": hashlib.sha256(mission_file.read_bytes()).hexdigest(), "seed": seed,
           "policy": str(Path(policy_dir).resolve())}
    label = f"twin: same mission, seed {seed}, policy {Path(policy_dir).name}"
    note = None if policy or recorded else f"twin policy assumed ({policy_dir}): the run did not record its policy"
    cache = run_dir / TWIN_CACHE
    try:
        cached = json.loads(cache.read_text())
        if cached.get("key") == key:
            return {"coverage": cached["coverage"], "label": label, "note": note}
    except (OSError, ValueError, AttributeError):
        pass
    from plmarl_sitl.bench.gap import twin_coverage
    from plmarl_sitl.mission import load_mission

    try:
        mission = load_mission(mission_file)
        if seed is None:
            seed = mission.seed
            key["seed"] = seed
            label = label.replace("seed None", f"seed {seed}")
        coverage = twin_coverage(mission, policy_dir, int(seed))
    except PlmarlError as exc:  # a policy that does not fit the mission, a missing file ...
        notes.append(f"no twin reference: {exc}")
        return None
    cache.write_text(json.dumps({"key": key, "coverage": coverage}))
    return {"coverage": coverage, "label": label, "note": note}
