#!/bin/sh
# session 23: the fewest-movers re-plan (service.FEWEST_MOVERS), v2: the old plan is the plan of the step's epoch
# (common knowledge). Two margins fixed before any result:
#   m1: MOVERS_MARGIN 1 user (REPLAN_MARGIN), m2: 2 % of the map's users (4.8 of 240)
# tuning seeds 7, 8; T_up 50 (replan, instant) then T_up 15 (replan; base too)
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session23/fail
P="nice -n 5 python $D/decompose.py --seeds 7 8 --episodes 10 --controllers service pl-marl"
$P --tup 50 --ways replan instant --movers > $D/m1_s7_8.json 2> $D/m1_s7_8.log
$P --tup 50 --ways replan instant --movers --movers-frac 0.02 > $D/m2_s7_8.json 2> $D/m2_s7_8.log
$P --tup 15 --ways replan > $D/base_t15_s7_8.json 2> $D/base_t15_s7_8.log
$P --tup 15 --ways replan --movers > $D/m1_t15_s7_8.json 2> $D/m1_t15_s7_8.log
$P --tup 15 --ways replan --movers --movers-frac 0.02 > $D/m2_t15_s7_8.json 2> $D/m2_t15_s7_8.log
