"""Imported once by the agents' forkserver (`sitl.forked`): everything `plmarl agent`
imports, so that a forked agent starts with them loaded, and the swarm's policy and plan
grid when the launcher named them (`forked.PRELOAD_ENV`, deploy/agent/preload.py). Nothing
here starts a thread: forking a process with threads (an OpenMP pool, an event loop) is unsafe."""

import gc
import json
import os

# As `plmarl agent` does: one BLAS/OpenMP thread per agent, set before torch loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import psutil  # noqa: E402, F401  (the agent reports its RSS with it)
import torch  # noqa: E402, F401

import plmarl_sitl.deploy.agent.core  # noqa: E402, F401
import plmarl_sitl.deploy.agent.preload  # noqa: E402
import plmarl_sitl.deploy.agent.program  # noqa: E402, F401
import plmarl_sitl.deploy.mavlink.connect  # noqa: E402, F401
import plmarl_sitl.deploy.mqtt.transport  # noqa: E402, F401
import plmarl_sitl.learning.nn.io  # noqa: E402, F401
import plmarl_sitl.mission  # noqa: E402, F401
import plmarl_sitl.sitl.forked  # noqa: E402, F401

_spec = os.environ.get(plmarl_sitl.sitl.forked.PRELOAD_ENV)
if _spec:
    try:
        plmarl_sitl.deploy.agent.preload.preload(**json.loads(_spec))
    except Exception:  # noqa: BLE001 - each agent then loads the files itself and reports what is wrong
        pass
# Everything loaded so far is shared copy-on-write with every agent. Frozen, the cyclic GC
# of an agent never walks (and so never writes to, and copies) the pages of these objects.
# Collected (and the freed heap trimmed) first: what is garbage now is neither frozen into
# every agent (126 ms of CPU per agent's first full collection otherwise, and its bookkeeping
# written into inherited pages) nor counted in every agent's RSS.
plmarl_sitl.deploy.agent.preload.release_free_heap()
gc.freeze()
