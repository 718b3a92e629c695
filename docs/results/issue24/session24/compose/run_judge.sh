#!/bin/sh
# H-compose24, step 2 (the judgement): fresh tuning seeds 15-18, 10 episodes per mission and seed,
# base (switch off) and CR (--compose-repairs), T_up 50 (replan, instant) and 15 (replan).
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session24/compose
P="nice -n 10 python $D/decompose.py --seeds 15 16 17 18 --episodes 10 --controllers service pl-marl"
$P --tup 50 --ways replan instant > $D/base_s15_18.json 2> $D/base_s15_18.log
$P --tup 50 --ways replan instant --compose-repairs > $D/cr_s15_18.json 2> $D/cr_s15_18.log
$P --tup 15 --ways replan > $D/base_t15_s15_18.json 2> $D/base_t15_s15_18.log
$P --tup 15 --ways replan --compose-repairs > $D/cr_t15_s15_18.json 2> $D/cr_t15_s15_18.log
