"""A policy and its team-plan grid loaded before the agent process exists.

A SITL swarm forks its agents from one forkserver (sitl/forked.py). When that server loads
the swarm's policy and builds the plan grid (model/service.py) before it forks, every agent
starts with them in place: 100 agents do not each spend CPU loading the same files while
the world waits for their vehicles (issue 25: start-up), and the pages are shared
copy-on-write between the agents instead of held once per agent (their PSS).

An agent uses the preloaded policy only when it names the same policy directory and mission
file (resolved paths, unchanged since the preload) and no override changes the mission;
otherwise it loads its own, with the usual checks and errors.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from plmarl_sitl.mission import Mission, load_mission

if TYPE_CHECKING:  # torch: imported where a policy is loaded, not by `plmarl agent`'s argument checks
    from plmarl_sitl.learning.nn.io import LoadedPolicy

_loaded: dict[tuple, LoadedPolicy] = {}
_missions: dict[tuple, Mission] = {}


def _key(policy: str | Path, mission: str | Path) -> tuple:
    files = [Path(policy).resolve() / name for name in ("card.yaml", "predictor.pt", "policy.pt")] + [Path(mission).resolve()]
    return tuple(_version(f) for f in files)


def _version(f: Path) -> tuple[str, int, int]:
    st = os.stat(f)
    return str(f), st.st_mtime_ns, st.st_size


def preload(policy: str | Path, mission: str | Path) -> None:
    """Load `policy` checked against the mission file `mission`, and build its plan grid."""
    from plmarl_sitl.learning.nn.io import dry_run, load_policy
    from plmarl_sitl.learning.nn.plan import service_grid

    m = load_mission(mission)
    _missions[_version(Path(mission).resolve())] = m  # frozen: shared by every agent as it is
    lp = load_policy(policy, m)
    # load_policy's dry run was each TorchScript method's profiling call; this second one
    # optimizes their graphs from that same profile, as each agent's first decision would
    # otherwise do for itself: done once here, the plans are shared by every agent instead of
    # each one running the JIT passes (their CPU, and ~3 MB of libtorch code pages in its RSS).
    dry_run(lp.tracker, lp.call)
    if lp.takes_plan and m.coordination == "team":  # the neighbourhood plan (coordination: local) needs no grid
        service_grid(m)  # cached by its constants: the agents' AgentPlan finds it built
    _loaded[_key(policy, mission)] = lp


def release_free_heap() -> None:
    """Collect, and give the freed heap (the loads' transients, the plan grid's build ~14 MB at
    3 km) back to the kernel: glibc keeps it resident otherwise. The forkserver calls it before
    its forks (an agent's RSS counts every anonymous page the server holds when it forks,
    garbage included), an agent once it is built. linecache holds the source lines `inspect`
    read while torch imported (code that needs one reads it again)."""
    import ctypes
    import gc
    import linecache

    linecache.clearcache()
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: nothing to trim
        pass


def preloaded(policy: str | Path, mission: str | Path) -> LoadedPolicy | None:
    """The policy preloaded for exactly these files, or None."""
    try:
        return _loaded.get(_key(policy, mission))
    except OSError:
        return None


def preloaded_mission(mission: str | Path) -> Mission | None:
    """The mission the forkserver loaded from exactly this file (unchanged since), or None.
    Its load warnings were said once, by the forkserver, not by each agent."""
    try:
        return _missions.get(_version(Path(mission).resolve()))
    except OSError:
        return None
