#!/bin/sh
# Session 20: the candidate flown by the agents (lockstep SITL, emulated autopilots) on session 19's
# probe_paper, beside the shipped pl-marl; one episode each, seed 0. Run from the repo root.
D=docs/results/issue24/session20/learn
export PYTHONPATH=.
for p in pl-marl policies/pl-marl-move; do
  t0=$(date +%s)
  python -m plmarl_sitl.cli swarm up docs/results/issue24/session19/move/probe_paper.yaml --lockstep --broker mosquitto \
    --headless --seed 0 --policy $p --out /tmp/l20/sitl_$(basename $p) 2>&1 | tail -12
  echo "== $p wall $(( $(date +%s) - t0 )) s"
done
