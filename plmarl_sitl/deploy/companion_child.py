"""An agent forked by a companion's forkserver (`deploy/companion.py`). The forkserver
imports PRELOAD once, everything `plmarl agent` needs: a host running several agents pays
the interpreter and torch start-up (~1.2 s of CPU) once and shares those pages between them.
This module itself stays light: the companion imports it for `run_agent` and must not load
torch (nor start a thread: forking a process with threads is unsafe)."""

import os
import sys

from plmarl_sitl.proc import agent_child_setup, output_to, set_process_name, sigterm_when_gone

# What the forkserver imports before it forks an agent (its environment already says one
# BLAS/OpenMP thread per agent: the companion sets it before the forkserver starts).
PRELOAD = [
    "plmarl_sitl.deploy.companion_child",
    "psutil",  # the agent reports its RSS with it
    "torch",
    "plmarl_sitl.deploy.agent.core",
    "plmarl_sitl.deploy.agent.program",
    "plmarl_sitl.deploy.mavlink.connect",
    "plmarl_sitl.deploy.mqtt.transport",
    "plmarl_sitl.learning.nn.io",
    "plmarl_sitl.mission",
]


def run_agent(argv: list[str], log_path: str, cwd: str, nice: int, companion: int, name: str) -> None:
    """The child: `plmarl agent ARGV` in `cwd`, its output to `log_path` (which the companion
    forwards); it stops (SIGTERM) when process `companion` exits, even by SIGKILL."""
    agent_child_setup(nice)
    sigterm_when_gone(companion)
    set_process_name(name)
    output_to(log_path, 0o600)  # a host's private directory: the log stays the host user's
    os.chdir(cwd)
    from plmarl_sitl.deploy.agent.program import main

    sys.exit(main(argv))
