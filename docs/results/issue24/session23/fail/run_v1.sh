#!/bin/sh
# session 23: the fewest-movers re-plan (service.FEWEST_MOVERS), v1 (commit 959bdcb), margin m1 only:
#   m1: MOVERS_MARGIN 1 user (REPLAN_MARGIN), m2: 2 % of the map's users (4.8 of 240)
# v1 (959bdcb): the old plan was the copy's plan of now; stopped after its first run (v1_m1_s7_8.*)
# tuning seeds 7, 8; T_up 50 (replan, instant) then T_up 15 (replan; base too)
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session23/fail
P="nice -n 5 python $D/decompose.py --seeds 7 8 --episodes 10 --controllers service pl-marl"
$P --tup 50 --ways replan instant --movers > $D/v1_m1_s7_8.json 2> $D/v1_m1_s7_8.log
