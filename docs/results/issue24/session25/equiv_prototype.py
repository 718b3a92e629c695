"""Equivalence: the product's failure_replan: local vs the s24-local-prototype's switches, same episodes.
Run from a checkout (the tag s24-local-prototype for proto, this commit for product):
    PYTHONPATH=. python docs/results/issue24/session25/equiv_prototype.py {proto|product} SEED OUT.npy
and compare the two .npy files (session 25: np.array_equal True, 16 episodes x 300 s)."""
import sys

import numpy as np

from plmarl_sitl.learning.eval.evaluate import controller_factory, run_method
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission

which, seed, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
loaded = {"pl-marl": load_policy("policies/pl-marl")}
res = []
for path in ["missions/suite/failure_2of6_a.yaml", "missions/suite/failure_2of6_b.yaml"]:
    m = load_mission(path).with_tup(50)
    for method in ["service", "pl-marl"]:
        if which == "proto":
            from plmarl_sitl.model import service
            service.COMPOSE_REPAIRS = service.LOCAL_REPAIRS = True
            make = controller_factory(method, loaded)
        else:
            make = controller_factory(method + "-local-repairs", loaded)
        r = run_method(m, make, 4, seed, batch=4)
        res.append(r.trace)
        print(path, method, r.coverage.round(5), flush=True)
np.save(out, np.stack(res))
