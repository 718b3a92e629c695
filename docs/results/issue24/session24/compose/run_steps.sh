#!/bin/sh
# H-compose24, information only (after the judgement): CR at T_up 50 (replan) on seeds 15-18 again, with the per-step
# log (cr_s15_18_steps.log) for prefix.py; its rows must equal cr_s15_18.json's (determinism).
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session24/compose
nice -n 10 python $D/decompose.py --seeds 15 16 17 18 --episodes 10 --controllers service pl-marl --tup 50 --ways replan \
    --compose-repairs --cr-log $D/cr_s15_18_steps.log > $D/cr_steps_s15_18.json 2> $D/cr_steps_s15_18.log
