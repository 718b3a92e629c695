#!/bin/sh
# H-hold26 judgement runs (fresh tuning seeds 29 30, 30 episodes per family), one heavy job at a time:
# T_up 50 first (with greedy once per family), then T_up 15 (the family `failure` is T_up 15 only: its greedy there).
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session26/hold
R="nice -n 10 python $D/runner.py --seeds 29 30 --episodes 30 --controllers pl-marl --variants base lr lr_hold"
F4="failure_2of6 failure_transit failure_split diffuse_failure"
echo "tup50 start $(date -u +%T)"; $R --tups 50 --families $F4 --greedy > $D/tup50_s29_30.json 2> $D/tup50_s29_30.log; echo "tup50 exit $? $(date -u +%T)"
echo "tup15 start $(date -u +%T)"; $R --tups 15 --families $F4 > $D/tup15_s29_30.json 2> $D/tup15_s29_30.log; echo "tup15 exit $? $(date -u +%T)"
echo "failure start $(date -u +%T)"; $R --tups 15 --families failure --greedy > $D/failure15_s29_30.json 2> $D/failure15_s29_30.log; echo "failure exit $? $(date -u +%T)"
