"""Imported once by the agents' forkserver (`sitl.forked`): everything `plmarl agent`
imports, so that a forked agent starts with them loaded. Nothing here starts a thread:
forking a process with threads (an OpenMP pool, an event loop) is unsafe."""

import gc
import os

# As `plmarl agent` does: one BLAS/OpenMP thread per agent, set before torch loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import psutil  # noqa: E402, F401  (the agent reports its RSS with it)
import torch  # noqa: E402, F401

import plmarl_sitl.deploy.agent.core  # noqa: E402, F401
import plmarl_sitl.deploy.agent.program  # noqa: E402, F401
import plmarl_sitl.deploy.mavlink.connect  # noqa: E402, F401
import plmarl_sitl.deploy.mqtt.transport  # noqa: E402, F401
import plmarl_sitl.learning.nn.io  # noqa: E402, F401
import plmarl_sitl.mission  # noqa: E402, F401
import plmarl_sitl.sitl.forked  # noqa: E402, F401

# Everything imported above lives as long as any agent: move it out of the collector's
# reach before the forks. A forked agent's own full collection before it flies
# (`VehicleSession.start`) then walks only what it allocated itself: 126 ms of CPU per
# agent otherwise, and writing the collector's bookkeeping into every inherited object
# copied those pages into each child (gc.freeze is meant for pre-fork servers).
gc.collect()
gc.freeze()
