#!/bin/sh
# session 22, c4: DECLARE_PRE_REPLAN as committed (PRE_REPLAN_MISSED 1, PRE_REPLAN_SEEN: own position and heard
# states at the newest instant, the silent teammate also at its last reported position, which its copy must
# have predicted within PRE_REPLAN_CHECK_M; only copies settled to what their agent knows)
cd /work/h-fail22
export PYTHONPATH=.
D=docs/results/issue24/session22/fail
python $D/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service pl-marl --ways replan --pre-replan --pre-replan-missed 1 --pre-replan-seen > $D/c4_prereplan_final_s7_8.json 2> $D/c4_prereplan_final_s7_8.log
