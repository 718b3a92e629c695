"""Run a bench module with session 22's DECLARE_PRE_REPLAN switched on as in c4 (twin only).

    PYTHONPATH=. python docs/results/issue24/session22/fail/with_prereplan.py plmarl_sitl.bench.replan ARGS...
"""
import runpy
import sys

from plmarl_sitl.learning.nn import plan as plan_mod

plan_mod.DECLARE_PRE_REPLAN = True
plan_mod.PRE_REPLAN_MISSED = 1
plan_mod.PRE_REPLAN_SEEN = True
module = sys.argv[1]
sys.argv = [module, *sys.argv[2:]]
runpy.run_module(module, run_name="__main__", alter_sys=True)
