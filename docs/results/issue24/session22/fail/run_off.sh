#!/bin/sh
# session 22: with every option off the prototype code flies main's episodes (T_up 50 base re-run) and the required tests pass
cd /work/h-fail22
while pgrep -f "run_checks.sh" >/dev/null; do sleep 3; done
export PYTHONPATH=.
D=docs/results/issue24/session22/fail
python $D/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service pl-marl --ways replan > $D/off_s7_8.json 2> $D/off_s7_8.log
date -u > $D/tests_off.log
python -m pytest -q tests/sitl/test_lockstep.py tests/model >> $D/tests_off.log 2>&1
date -u >> $D/tests_off.log
