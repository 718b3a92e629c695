#!/bin/bash
# Twin-to-SITL gap with local repairs on station the default (session 27), lockstep, T_up 50, seeds 0 1.
cd /work/main
D=docs/results/issue24/session27/gap_lrs
for m in failure_2of6_a failure_2of6_b failure_transit failure_split diffuse_failure; do
  python -m plmarl_sitl.bench.gap docs/results/issue24/session27/gap_heard/t50_$m.yaml --seeds 0 1 --lockstep --speedup 10 --start-wall-s 600 --json > $D/$m.json 2> $D/$m.log
done
echo done > $D/DONE
