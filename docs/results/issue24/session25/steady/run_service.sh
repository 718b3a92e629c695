#!/bin/sh
# H-steady25: `service` beside (after run_all.sh; one heavy job at a time), same episodes, with the diagnostics fields.
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session25/steady
while ! grep -q "^done plmarl" $D/run_all.log; do sleep 10; done
R="nice -n 10 python $D/runner.py --seeds 27 28 --episodes 30"
echo "service all $(date -u +%T)"; $R --controllers service > $D/service_s27_28.json 2> $D/service_s27_28.log
echo "done service $(date -u +%T)"
