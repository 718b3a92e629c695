#!/bin/sh
# H-local24, step 3 (the judgement): fresh tuning seeds 19-22, 10 episodes per mission and seed,
# base (switch off) and LR (--local-repairs), T_up 50 and 15 (replan); then the tests with the
# switch off; then, for information, T_up 50 instant (base and LR).
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session24/local
P="nice -n 10 python $D/decompose.py --seeds 19 20 21 22 --episodes 10 --controllers service pl-marl"
echo "base50 $(date -u +%T)"; $P --tup 50 --ways replan > $D/base_s19_22.json 2> $D/base_s19_22.log
echo "lr50 $(date -u +%T)"; $P --tup 50 --ways replan --local-repairs --cr-log $D/lr_s19_22_steps.log > $D/lr_s19_22.json 2> $D/lr_s19_22.log
echo "base15 $(date -u +%T)"; $P --tup 15 --ways replan > $D/base_t15_s19_22.json 2> $D/base_t15_s19_22.log
echo "lr15 $(date -u +%T)"; $P --tup 15 --ways replan --local-repairs > $D/lr_t15_s19_22.json 2> $D/lr_t15_s19_22.log
echo "tests $(date -u +%T)"; nice -n 10 python -m pytest -q tests/model > $D/tests_off.log 2>&1
echo "instant $(date -u +%T)"; $P --tup 50 --ways instant > $D/base_instant_s19_22.json 2> $D/base_instant_s19_22.log
$P --tup 50 --ways instant --local-repairs > $D/lr_instant_s19_22.json 2> $D/lr_instant_s19_22.log
echo "done $(date -u +%T)"
