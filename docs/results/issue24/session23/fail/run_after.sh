#!/bin/sh
# session 23, after the verdict on seeds 7, 8 (no candidate): options off (the required tests), then, for
# information only, m1 and m2 on tuning seeds 9, 10 (replan way; the base there is session 22's base_s9_10.json,
# since main reproduced session 22's base on seeds 7, 8 episode by episode)
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session23/fail
date -u > $D/tests_off.log
nice -n 5 python -m pytest -q tests/sitl/test_lockstep.py tests/model >> $D/tests_off.log 2>&1
date -u >> $D/tests_off.log
P="nice -n 5 python $D/decompose.py --seeds 9 10 --episodes 10 --controllers service pl-marl --tup 50 --ways replan"
$P --movers > $D/m1_s9_10.json 2> $D/m1_s9_10.log
$P --movers --movers-frac 0.02 > $D/m2_s9_10.json 2> $D/m2_s9_10.log
