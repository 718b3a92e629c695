#!/bin/bash
# Twin-to-SITL gap with transit_plan_m: 300 (session 28), lockstep, T_up 50, seeds 0 1.
cd "$(git rev-parse --show-toplevel)"
D=docs/results/issue24/session28/gap_transit300
for m in failure_transit thin_area_a; do
  python -m plmarl_sitl.bench.gap $D/t50_transit300_$m.yaml --seeds 0 1 --lockstep --speedup 10 --start-wall-s 600 --json > $D/$m.json 2> $D/$m.log
done
