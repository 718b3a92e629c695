#!/bin/sh
# A failure off the common instants (120 s at T_up 50): phased against common instants (service, seeds 7, 8).
cd /work/h-fail21
while pgrep -f "pytest -q -p no:cacheprovider tests/sitl/test_lockstep.py" >/dev/null; do sleep 3; done
export PYTHONPATH=.
python docs/results/issue24/session21/fail/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service --ways replan instant phased --fail-s 120 --missions docs/results/issue24/session21/fail/missions/failure_2of6_a_at120.yaml docs/results/issue24/session21/fail/missions/failure_2of6_b_at120.yaml > docs/results/issue24/session21/fail/e9_at120_s7_8.json 2> docs/results/issue24/session21/fail/e9_at120_s7_8.log
