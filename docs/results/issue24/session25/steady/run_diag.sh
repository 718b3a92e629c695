#!/bin/sh
# H-steady25 diagnostic (after run_service.sh): pl-marl again on the same episodes with --attribute
# (each new declaration booked by rule and truth). Coverage must repeat the judgement run's.
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session25/steady
while ! grep -q "^done service" $D/run_service.log; do sleep 10; done
R="nice -n 10 python $D/runner.py --seeds 27 28 --episodes 30 --attribute"
echo "diag plmarl $(date -u +%T)"; $R --controllers pl-marl > $D/diag_plmarl_s27_28.json 2> $D/diag_plmarl_s27_28.log
echo "done diag $(date -u +%T)"
