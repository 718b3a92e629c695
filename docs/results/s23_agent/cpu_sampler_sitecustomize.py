"""A CPU-time sampler for every agent of a `swarm up` run (session 23; a measuring tool, not part of the package).

Put this file's directory on PYTHONPATH as `sitecustomize.py` (copy or symlink it under that name), after the tree:
    mkdir -p /tmp/prof && PROF_AGENTS=/tmp/prof PYTHONPATH=TREE:/tmp/sampler python3 -m plmarl_sitl.cli swarm up ...
Each agent's `program.main` is wrapped (an import hook: the fork server imports the module) to record its Python stack
at every SIGPROF of ITIMER_PROF (process CPU, user + system; 1 ms asked, the kernel's tick delivers one per ~4 ms of
CPU), written as folded stacks to $PROF_AGENTS/<pid>.txt when the agent ends. Unlike py-spy's wall samples it counts
no time spent waiting for a core; a system call's time is booked to the line that made it or to the next line the
handler sees (see fold.py / sub.py)."""
import os
import sys

OUT = os.environ.get("PROF_AGENTS")
if OUT:
    import collections
    import importlib.abc
    import importlib.util
    import re
    import signal

    def _where(code):
        return re.sub(r"^.*?/(plmarl_sitl|site-packages|python3\.\d+)/", r"\1/", code.co_filename)

    def wrap(mod):
        orig = mod.main

        def main(argv):
            counts = collections.Counter()

            def on_prof(sig, frame):
                st = []
                while frame is not None:
                    st.append(f"{frame.f_code.co_qualname} ({_where(frame.f_code)}:{frame.f_lineno})")
                    frame = frame.f_back
                counts[";".join(reversed(st))] += 1

            signal.signal(signal.SIGPROF, on_prof)
            signal.setitimer(signal.ITIMER_PROF, 0.001, 0.001)
            try:
                return orig(argv)
            finally:
                signal.setitimer(signal.ITIMER_PROF, 0, 0)
                with open(f"{OUT}/{os.getpid()}.txt", "w") as fh:
                    for k, v in counts.items():
                        fh.write(f"{k} {v}\n")

        mod.main = main

    class Finder(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path, target=None):
            if name != "plmarl_sitl.deploy.agent.program":
                return None
            sys.meta_path.remove(self)
            try:
                spec = importlib.util.find_spec(name)
            finally:
                sys.meta_path.insert(0, self)
            exec_module = spec.loader.exec_module

            def exec_and_wrap(module):
                exec_module(module)
                wrap(module)

            spec.loader.exec_module = exec_and_wrap
            return spec

    sys.meta_path.insert(0, Finder())
