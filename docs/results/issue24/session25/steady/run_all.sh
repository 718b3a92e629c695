#!/bin/sh
# H-steady25 judgement runs (fresh tuning seeds 27 28, 30 episodes per family), one heavy job at a time.
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session25/steady
R="nice -n 10 python $D/runner.py --seeds 27 28 --episodes 30"
echo "plmarl 2of6 $(date -u +%T)"; $R --families failure_2of6 --greedy --controllers pl-marl > $D/plmarl_2of6_s27_28.json 2> $D/plmarl_2of6_s27_28.log
echo "plmarl rest $(date -u +%T)"; $R --families failure_transit failure_split diffuse_failure failure --controllers pl-marl > $D/plmarl_rest_s27_28.json 2> $D/plmarl_rest_s27_28.log
echo "done plmarl $(date -u +%T)"
