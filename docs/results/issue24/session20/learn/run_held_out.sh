#!/bin/sh
# Session 20 held-out runs (suite run seeds 2391, 2392: never used before). Run from the repo root.
set -e
D=docs/results/issue24/session20/learn
export PYTHONPATH=.
for s in 2391 2392; do
  python $D/held_out.py moving_demand --seed $s --methods service,service-track,pl-marl,pl-marl-track \
    --policy policies/pl-marl-move --tup 15,50 --episodes 30 --out $D/held_out_s$s.json > $D/held_out_s$s.txt 2>&1
done
for s in 2391 2392; do
  python $D/held_out.py moving_demand --seed $s --methods service,service-track \
    --policy $D/policies/move-c --tup 15,50 --episodes 30 --out $D/held_out_movec_s$s.json > $D/held_out_movec_s$s.txt 2>&1
done
python $D/held_out.py paper,failure_2of6,thin_area --seed 2391 --methods service,pl-marl \
  --policy policies/pl-marl-move --policy-methods move --tup 15,50 --episodes 30 --out $D/static_s2391.json > $D/static_s2391.txt 2>&1
# the suite's own table (its MWU p is PL-MARL's against each row): the candidate as `pl-marl` via --policies
mkdir -p /tmp/l20/pol-move && ln -sfn "$(pwd)/policies/pl-marl-move" /tmp/l20/pol-move/pl-marl
for s in 2391 2392; do
  python -m plmarl_sitl.cli suite moving_demand --methods service,service-track,pl-marl,pl-marl-track --policies /tmp/l20/pol-move \
    --tup 15,50 --episodes 30 --seed $s --out $D/suite_move_s$s > $D/suite_move_s$s.txt 2>&1
done
echo done
