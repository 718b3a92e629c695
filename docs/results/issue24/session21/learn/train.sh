#!/bin/sh
# Session 21 (H-learn21): the default recipe (session 20) plus long transits. Run from the worktree root.
# usage: sh docs/results/issue24/session21/learn/train.sh SEED SHARE OUT [extra plmarl train flags]
seed=$1; share=$2; out=$3; shift 3
PYTHONPATH=. python -m plmarl_sitl.cli train --method pl-marl --predictor policies/plan/pl-marl/predictor.pt --teacher track \
  --teacher-track-m 30 --teacher-track-link 0.7 --moving-share 0.5 --transit-share "$share" --episodes 16 --seed "$seed" \
  --eval-episodes 0 --out "$out" "$@"
