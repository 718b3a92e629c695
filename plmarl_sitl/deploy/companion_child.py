"""An agent forked by a companion's forkserver (`deploy/companion.py`), which imported this
module and everything `plmarl agent` needs once: a host running several agents pays the
interpreter and torch start-up (~1.2 s of CPU) once and shares those pages between them.
Nothing here starts a thread at import: forking a process with threads is unsafe."""

import os
import sys

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
from plmarl_sitl.proc import agent_child_setup, set_process_name, sigterm_when_gone  # noqa: E402


def run_agent(argv: list[str], log_path: str, cwd: str, nice: int, companion: int, name: str) -> None:
    """The child: `plmarl agent ARGV` in `cwd`, its output to `log_path` (which the companion
    forwards); it stops (SIGTERM) when process `companion` exits, even by SIGKILL."""
    agent_child_setup(nice)
    sigterm_when_gone(companion)
    set_process_name(name)
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    sys.stdout.reconfigure(line_buffering=True)  # type: ignore[union-attr]
    sys.stderr.reconfigure(line_buffering=True)  # type: ignore[union-attr]
    os.chdir(cwd)
    from plmarl_sitl.deploy.agent.program import main

    sys.exit(main(argv))
