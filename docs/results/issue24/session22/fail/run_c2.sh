#!/bin/sh
# session 22: the candidate (DECLARE_PRE_REPLAN) on the base's 40 episodes, after the base run
cd /work/h-fail22
while kill -0 "$1" 2>/dev/null; do sleep 3; done
export PYTHONPATH=.
D=docs/results/issue24/session22/fail
python $D/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service pl-marl --ways replan --pre-replan > $D/c2_prereplan_s7_8.json 2> $D/c2_prereplan_s7_8.log
