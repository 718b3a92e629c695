"""usage: standalone_agent0.py SWARM-UP-ARGS...: `plmarl swarm up` with agent 0 exec'd as a
standalone `python -m plmarl_sitl.cli agent ...` (what a companion computer runs) and agents
1..N-1 forked from the forkserver as usual; for comparing a standalone agent's memory with a
forked one's in the same mission (Session 15, issue 24.2). A measurement harness, not a tool."""
import asyncio
import functools
import os
import sys

import plmarl_sitl.sitl.agents as agents
from plmarl_sitl.cli import main
from plmarl_sitl.proc import agent_child_setup

forked = agents.fork_agent


async def fork_or_exec(argv, log_path, env, name, nice=0):  # noqa: ANN001, ANN201
    if name != "plmarl-agent0":
        return await forked(argv, log_path, env, name=name, nice=nice)
    with open(log_path, "wb") as log:
        return await asyncio.create_subprocess_exec(
            sys.executable, "-m", "plmarl_sitl.cli", "agent", *argv, stdout=log, stderr=asyncio.subprocess.STDOUT,
            env=dict(os.environ, **env), preexec_fn=functools.partial(agent_child_setup, nice))


if __name__ == "__main__":  # not when the forkserver imports this file as its __main__
    agents.fork_agent = fork_or_exec
    sys.exit(main(["swarm", "up", *sys.argv[1:]]))
