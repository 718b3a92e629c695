#!/bin/sh
# H-confirm25, Task 2 part 2: LR (--local-repairs) on fresh tuning seeds 23-26, T_up 50 (with the step log) and 15 (replan),
# after run_base.sh (one heavy job at a time). LR code unchanged from s24-local-prototype (the trace found no LR bug).
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
L=docs/results/issue24/session24/local
D=docs/results/issue24/session25/confirm
while ! grep -q "^done" $D/run_base.log; do sleep 10; done
P="nice -n 10 python $L/decompose.py --seeds 23 24 25 26 --episodes 10 --controllers service pl-marl"
echo "lr50 $(date -u +%T)"; $P --tup 50 --ways replan --local-repairs --cr-log $D/lr_s23_26_steps.log > $D/lr_s23_26.json 2> $D/lr_s23_26.log
echo "lr15 $(date -u +%T)"; $P --tup 15 --ways replan --local-repairs > $D/lr_t15_s23_26.json 2> $D/lr_t15_s23_26.log
echo "done $(date -u +%T)"
