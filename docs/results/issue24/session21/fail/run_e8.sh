#!/bin/sh
cd /work/h-fail21
while pgrep -f "decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service --ways replan --leash --alone" >/dev/null; do sleep 3; done
export PYTHONPATH=.
python docs/results/issue24/session21/fail/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service --ways replan --rejoin --guard-lag-s 100 > docs/results/issue24/session21/fail/e8_lag_rejoin_s7_8.json 2> docs/results/issue24/session21/fail/e8_lag_rejoin_s7_8.log
