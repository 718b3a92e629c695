#!/bin/sh
# session 24, step 2 (the judgement): fresh tuning seeds 11-14, 10 episodes per mission and seed,
# base (switch off) and SG (--split-gate, margin m2 = 2 % of the map's users), T_up 50 (replan, instant) and 15 (replan).
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session24/fail
P="nice -n 5 python $D/decompose.py --seeds 11 12 13 14 --episodes 10 --controllers service pl-marl"
$P --tup 50 --ways replan instant > $D/base_s11_14.json 2> $D/base_s11_14.log
$P --tup 50 --ways replan instant --split-gate --movers-frac 0.02 > $D/sg_s11_14.json 2> $D/sg_s11_14.log
$P --tup 15 --ways replan > $D/base_t15_s11_14.json 2> $D/base_t15_s11_14.log
$P --tup 15 --ways replan --split-gate --movers-frac 0.02 > $D/sg_t15_s11_14.json 2> $D/sg_t15_s11_14.log
