#!/bin/sh
# session 22: c4 against the base on two more tuning seeds (9, 10), after the verdict (information only; the rule was applied on 7, 8)
cd /work/h-fail22
while pgrep -f "run_off.sh" >/dev/null; do sleep 3; done
export PYTHONPATH=.
D=docs/results/issue24/session22/fail
python $D/decompose.py --seeds 9 10 --episodes 10 --tup 50 --controllers service pl-marl --ways replan > $D/base_s9_10.json 2> $D/base_s9_10.log
python $D/decompose.py --seeds 9 10 --episodes 10 --tup 50 --controllers service pl-marl --ways replan --pre-replan --pre-replan-missed 1 --pre-replan-seen > $D/c4_s9_10.json 2> $D/c4_s9_10.log
