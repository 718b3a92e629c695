#!/bin/sh
# H-compose24, step 1 (sanity, bugs only): the switch off must reproduce session 24's fail/base_s7_8.json
# episode by episode; composable repairs (CR) on the same seeds, one log line per re-plan step (cr_s7_8_steps.log).
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session24/compose
P="nice -n 10 python $D/decompose.py --seeds 7 8 --episodes 10 --controllers service pl-marl"
$P --tup 50 --ways replan instant > $D/base_s7_8.json 2> $D/base_s7_8.log
$P --tup 50 --ways replan instant --compose-repairs --cr-log $D/cr_s7_8_steps.log > $D/cr_s7_8.json 2> $D/cr_s7_8.log
