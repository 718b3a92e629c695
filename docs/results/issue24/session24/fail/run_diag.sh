#!/bin/sh
# session 24, after the verdict (diagnosis only): how far the split gate's condition is from firing, per re-plan step
cd "$(dirname "$0")/../../../../.." || exit 1
export PYTHONPATH=.
D=docs/results/issue24/session24/fail
for c in "13 b 50" "14 b 50" "11 a 50" "8 b 50" "13 b 15" "14 b 15"; do
  set -- $c
  echo "== seed $1 failure_2of6_$2 T_up $3 pl-marl"
  nice -n 5 python $D/diag_gate.py $1 missions/suite/failure_2of6_$2.yaml $3 pl-marl
done
