"""Does the heard-link rule change the twin episodes of the gap seeds? twin_coverage with the rule (default)
and with it off (HEARD_MARGIN_DB = 200.0: no link qualifies)."""
import sys
from plmarl_sitl.bench.gap import twin_coverage
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model import gossip
D = "docs/results/issue24/session27/gap_heard"
for m in ["failure_2of6_a", "failure_2of6_b", "failure_transit", "failure_split", "diffuse_failure"]:
    mi = load_mission(f"{D}/t50_{m}.yaml")
    for s in (0, 1):
        gossip.HEARD_MARGIN_DB = 3.0
        on = twin_coverage(mi, "policies/pl-marl", s)
        gossip.HEARD_MARGIN_DB = 200.0
        off = twin_coverage(mi, "policies/pl-marl", s)
        print(f"{m} seed {s}: with rule {sum(on)/len(on):.4f} without {sum(off)/len(off):.4f} seconds differing {sum(a != b for a, b in zip(on, off))}", flush=True)
