#!/bin/sh
# H-local24, step 2 (sanity, bugs only): the switch off must reproduce session 24's fail/base_s7_8.json
# episode by episode; local repairs (LR) on the same seeds, one log line per re-plan step with each
# repair's allowed rows (f's neighbours in P0) and movers (lr_s7_8_steps.log).
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session24/local
P="nice -n 10 python $D/decompose.py --seeds 7 8 --episodes 10 --controllers service pl-marl"
$P --tup 50 --ways replan instant > $D/base_s7_8.json 2> $D/base_s7_8.log
python docs/results/issue24/session24/fail/same_base.py docs/results/issue24/session24/fail/base_s7_8.json $D/base_s7_8.json > $D/same_base_s7_8.txt 2>&1
$P --tup 50 --ways replan instant --local-repairs --cr-log $D/lr_s7_8_steps.log > $D/lr_s7_8.json 2> $D/lr_s7_8.log
