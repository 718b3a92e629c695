#!/bin/sh
cd /work/h-fail21
export PYTHONPATH=.
python docs/results/issue24/session21/fail/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service --ways replan --leash --alone > docs/results/issue24/session21/fail/e6_leash_alone_s7_8.json 2> docs/results/issue24/session21/fail/e6_leash_alone_s7_8.log
python docs/results/issue24/session21/fail/decompose.py --seeds 7 8 --episodes 10 --tup 50 --controllers service --ways replan --leash --alone --rejoin > docs/results/issue24/session21/fail/e7_leash_alone_rejoin_s7_8.json 2> docs/results/issue24/session21/fail/e7_leash_alone_rejoin_s7_8.log
