#!/bin/sh
# Session 21 experiments, service, tuning seeds 7 and 8, T_up 50, 10 episodes per mission (one after the other).
cd /work/h-fail21
while kill -0 30963 2>/dev/null; do sleep 5; done
export PYTHONPATH=.
python docs/results/issue24/session21/fail/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service --ways replan --guard-lag-s 100 > docs/results/issue24/session21/fail/e1_lag100_s7_8.json 2> docs/results/issue24/session21/fail/e1_lag100_s7_8.log
python docs/results/issue24/session21/fail/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service --ways replan --hold > docs/results/issue24/session21/fail/e3_hold_s7_8.json 2> docs/results/issue24/session21/fail/e3_hold_s7_8.log
python docs/results/issue24/session21/fail/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service --ways replan --hold --guard-lag-s 100 > docs/results/issue24/session21/fail/e13_s7_8.json 2> docs/results/issue24/session21/fail/e13_s7_8.log
