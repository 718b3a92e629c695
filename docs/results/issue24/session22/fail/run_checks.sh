#!/bin/sh
# session 22: the candidate's side checks (after c4): T_up 15 on the same missions (seeds 7, 8), and false
# declarations on failure-free missions (bench.declare, seed 7), base (options off) and candidate
cd /work/h-fail22
while pgrep -f "run_c4.sh" >/dev/null; do sleep 3; done
export PYTHONPATH=.
D=docs/results/issue24/session22/fail
python $D/decompose.py --seeds 7 8 --episodes 10 --tup 15 --controllers service pl-marl --ways replan > $D/base_t15_s7_8.json 2> $D/base_t15_s7_8.log
python $D/decompose.py --seeds 7 8 --episodes 10 --tup 15 --controllers service pl-marl --ways replan --pre-replan --pre-replan-missed 1 --pre-replan-seen > $D/c4_t15_s7_8.json 2> $D/c4_t15_s7_8.log
python -m plmarl_sitl.bench.declare missions/paper_urban.yaml missions/blackout.yaml missions/broker_outage.yaml --tup 15 50 --episodes 20 --seed 7 --methods service policies/pl-marl --json > $D/declare_base_s7.json 2> $D/declare_base_s7.log
python $D/with_prereplan.py plmarl_sitl.bench.declare missions/paper_urban.yaml missions/blackout.yaml missions/broker_outage.yaml --tup 15 50 --episodes 20 --seed 7 --methods service policies/pl-marl --json > $D/declare_c4_s7.json 2> $D/declare_c4_s7.log
