#!/bin/sh
# session 22, second batch: c3 (DECLARE_PRE_REPLAN at the newest instant, as seen then) and c1b (PIN_UNAWARE + PIN_QUIET)
cd /work/h-fail22
while pgrep -f "run_c.sh" >/dev/null; do sleep 3; done
export PYTHONPATH=.
D=docs/results/issue24/session22/fail
python $D/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service pl-marl --ways replan --pre-replan --pre-replan-missed 1 --pre-replan-seen > $D/c3_prereplan_seen_s7_8.json 2> $D/c3_prereplan_seen_s7_8.log
python $D/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service pl-marl --ways replan --pin --pin-quiet > $D/c1b_pin_quiet_s7_8.json 2> $D/c1b_pin_quiet_s7_8.log
