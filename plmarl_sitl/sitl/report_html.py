"""report.html: one self-contained file for a run (`plmarl report RUN --html`): the summary
table, the events, and the plots embedded as base64 PNGs, so it can be mailed or attached
to a paper's supplement without its run directory.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

from plmarl_sitl.sitl.report_events import event_label
from plmarl_sitl.sitl.summary import transient_label

CSS = """body{font-family:system-ui,sans-serif;max-width:1000px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:.3em .6em;text-align:left}
td.n{text-align:right;font-variant-numeric:tabular-nums}img{max-width:100%;border:1px solid #eee}
figure{margin:1.5em 0}figcaption{color:#555;font-size:.9em}code{background:#f4f4f4;padding:0 .2em}"""

CAPTIONS = {
    "coverage.png": "Coverage C(t) of the run and, dashed, the twin's run of the same mission, seed and policy; "
                    "events marked and named; green: the band coverage must return to for a failure to count as "
                    "recovered. Below: lambda_2 of the live swarm's U2U graph (0: the swarm is split).",
    "aoi.png": "Largest P-AoI among the neighbours each UAV holds, per second; light grey: no neighbour held; "
               "dark: the UAV is lost (red X: when).",
    "trajectories.png": "Tracks over the replayed users and their cluster centres; the launch line; a lost UAV's "
                        "track ends in a red X; U2U links every 20 s (faded) and at the last second (dashed).",
}


def summary_rows(summary: dict) -> list[tuple[str, str]]:
    """(metric, value) rows: the same figures `print_summary` shows in the terminal."""
    rows = [("coverage mean", f"{summary['coverage_mean']:.3f}"), ("coverage min", f"{summary['coverage_min']:.3f}"),
            ("duration", f"{summary['duration_s']:.0f} s (speedup {summary['speedup']})")]
    if summary.get("seed") is not None:
        rows.append(("seed", str(summary["seed"])))
    if summary.get("policy"):
        rows.append(("policy", str(summary["policy"])))
    if summary.get("autopilot"):
        rows.append(("autopilot", str(summary["autopilot"])))
    rows.append(("events", str(len(summary["events"]))))
    for f in summary.get("node_failures", []):
        who = f" (UAV {f['uav']})" if f.get("uav") is not None else ""
        rows.append((f"failure at {f['at_s']:.0f} s{who}", f.get("label") or transient_label(f)))
    return rows


def write_html(path: Path, title: str, summary: dict, events: list[dict], pngs: list[Path], notes: list[str] = ()) -> Path:
    e = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title><style>{CSS}</style></head><body>",
             f"<h1>{e(title)}</h1>"]
    parts += [f"<p>{e(n)}</p>" for n in notes]
    parts.append("<h2>Summary</h2><table><tr><th>metric</th><th>value</th></tr>")
    parts += [f"<tr><td>{e(k)}</td><td class='n'>{e(v)}</td></tr>" for k, v in summary_rows(summary)]
    parts.append("</table><h2>Events</h2>")
    if events:
        parts.append("<table><tr><th>t [s]</th><th>event</th><th>recorded as</th></tr>")
        parts += [f"<tr><td class='n'>{ev['t']:g}</td><td>{e(event_label(ev))}</td><td><code>{e(ev.get('type', '?'))}</code></td></tr>"
                  for ev in events]
        parts.append("</table>")
    else:
        parts.append("<p>none</p>")
    parts.append("<h2>Plots</h2>")
    for png in pngs:
        data = base64.b64encode(png.read_bytes()).decode("ascii")
        parts.append(f"<figure><img alt='{e(png.name)}' src='data:image/png;base64,{data}'>"
                     f"<figcaption><b>{e(png.name)}</b>: {e(CAPTIONS.get(png.name, ''))}</figcaption></figure>")
    parts.append("<p>Per-second numbers: <code>metrics.csv</code> and <code>metrics.jsonl</code> in the run directory.</p>")
    parts.append("</body></html>")
    path.write_text("\n".join(parts))
    return path
