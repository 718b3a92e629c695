#!/bin/sh
# session 24, step 1 (sanity, not a judgement): the base with the switch off must reproduce session 23's
# base_s7_8.json (replan, instant rows) episode by episode; the split gate (SG: fewest movers with margin m2,
# 2 % of the map's users, only where the full re-solve is split-prone) on the same seeds, to find bugs.
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session24/fail
P="nice -n 5 python $D/decompose.py --seeds 7 8 --episodes 10 --controllers service pl-marl"
$P --tup 50 --ways replan instant > $D/base_s7_8.json 2> $D/base_s7_8.log
$P --tup 50 --ways replan instant --split-gate --movers-frac 0.02 > $D/sg_s7_8.json 2> $D/sg_s7_8.log
