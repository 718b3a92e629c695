#!/bin/sh
# session 22: the candidates on the base's 40 episodes (seeds 7, 8; T_up 50), one after another
cd /work/h-fail22
export PYTHONPATH=.
D=docs/results/issue24/session22/fail
# c2: DECLARE_PRE_REPLAN, silent at 1 instant (first run, before PRE_REPLAN_MISSED existed: same as --pre-replan-missed 1)
# python $D/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service pl-marl --ways replan --pre-replan > $D/c2_prereplan_s7_8.json 2> $D/c2_prereplan_s7_8.log
# c2b: the same, silent at the 2 newest instants
python $D/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service pl-marl --ways replan --pre-replan --pre-replan-missed 2 > $D/c2b_prereplan2_s7_8.json 2> $D/c2b_prereplan2_s7_8.log
# c1: PIN_UNAWARE
python $D/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service pl-marl --ways replan --pin > $D/c1_pin_s7_8.json 2> $D/c1_pin_s7_8.log
