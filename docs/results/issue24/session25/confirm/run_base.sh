#!/bin/sh
# H-confirm25, Task 2 part 1: the base (switches off) on fresh tuning seeds 23-26, 10 episodes per mission and seed,
# T_up 50 and 15 (replan). Same commands as session24/local/run_judge.sh with the seeds changed.
# (Started before the trace: the base does not run any LR code, so a fix to LR cannot change it.)
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
L=docs/results/issue24/session24/local
D=docs/results/issue24/session25/confirm
P="nice -n 10 python $L/decompose.py --seeds 23 24 25 26 --episodes 10 --controllers service pl-marl"
echo "base50 $(date -u +%T)"; $P --tup 50 --ways replan > $D/base_s23_26.json 2> $D/base_s23_26.log
echo "base15 $(date -u +%T)"; $P --tup 15 --ways replan > $D/base_t15_s23_26.json 2> $D/base_t15_s23_26.log
echo "done $(date -u +%T)"
