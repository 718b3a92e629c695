"""The agents' fork server (`sitl/forked.py` starts it and talks to it) and each agent it forks.

Imported by the server only, never by the launcher: everything `plmarl agent` imports, so
that a forked agent starts with them loaded, and (on a "preload" request) the swarm's
policy and plan grid (deploy/agent/preload.py). The server runs one thread and no event
loop: forking a process with threads (an OpenMP pool, an event loop) is unsafe.
`python -m plmarl_sitl.sitl.forked_child FD LAUNCHER_PID` runs the server in a fresh
interpreter, on the socket FD (the launcher could not fork it: it runs threads).
"""

import gc
import json
import os
import selectors
import signal
import socket
import sys

from plmarl_sitl.sitl.fork_protocol import MAX_MESSAGE, SERVER_NAME, THREADS_ENV

# As `plmarl agent` does: one BLAS/OpenMP thread per agent, set before torch loads (a server
# forked from the launcher shares the launcher's, which `forked.start_server` set alike).
for _name, _value in THREADS_ENV.items():
    os.environ.setdefault(_name, _value)

import psutil  # noqa: E402  (the agent reports its RSS with it)
import torch  # noqa: E402, F401

import plmarl_sitl.deploy.agent.core  # noqa: E402, F401
import plmarl_sitl.deploy.agent.preload  # noqa: E402
import plmarl_sitl.deploy.agent.program  # noqa: E402, F401
import plmarl_sitl.deploy.mavlink.connect  # noqa: E402, F401
import plmarl_sitl.deploy.mqtt.transport  # noqa: E402, F401
import plmarl_sitl.learning.nn.io  # noqa: E402, F401
import plmarl_sitl.mission  # noqa: E402, F401
from plmarl_sitl.proc import agent_child_setup, die_with_parent, output_to, set_process_name, sigterm_when_gone  # noqa: E402


def _share() -> None:
    """Everything loaded so far is shared copy-on-write with every agent. Frozen, the cyclic
    GC of an agent never walks (and so never writes to, and copies) the pages of these objects.
    Collected (and the freed heap trimmed) first: what is garbage now is neither frozen into
    every agent (126 ms of CPU per agent's first full collection otherwise, and its bookkeeping
    written into inherited pages) nor counted in every agent's RSS."""
    plmarl_sitl.deploy.agent.preload.release_free_heap()
    gc.freeze()


def serve(sock: socket.socket, launcher: int) -> None:
    """The server's loop: answer each request in order until the socket's end of file (the
    launcher closed it, or is gone), reporting each agent's exit; then exit (any agent still
    running gets SIGTERM: PR_SET_PDEATHSIG)."""
    die_with_parent()
    if os.getppid() != launcher:  # the launcher died before the line above
        return
    set_process_name(SERVER_NAME)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C: the launcher stops the agents, then closes the socket
    devnull = os.open(os.devnull, os.O_RDONLY)  # nothing an agent runs reads the launcher's terminal
    os.dup2(devnull, 0)
    os.close(devnull)
    _share()
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    signal.signal(signal.SIGCHLD, lambda *_: None)  # the byte on wake_w is what wakes the loop
    signal.set_wakeup_fd(wake_w)
    sel = selectors.DefaultSelector()
    sel.register(sock, selectors.EVENT_READ)
    sel.register(wake_r, selectors.EVENT_READ)

    def send(msg: dict) -> None:
        sock.sendall(json.dumps(msg).encode())

    try:
        while True:
            for key, _ in sel.select():
                if key.fileobj is wake_r:
                    os.read(wake_r, 4096)
                    _report_exits(send)
                    continue
                data = sock.recv(MAX_MESSAGE)
                if not data:
                    return
                req = json.loads(data)
                if req["op"] == "preload":
                    send({"op": "preloaded", "result": _preload(req["policy"], req["mission"])})
                elif req["op"] == "fork":
                    try:
                        pid = os.fork()
                    except OSError as exc:  # out of memory or processes: this agent fails, the server goes on
                        send({"op": "failed", "result": f"cannot fork {req['name']}: {exc}"})
                        continue
                    if pid == 0:
                        _agent(req, closing=(sel, sock, wake_r, wake_w))
                    send({"op": "forked", "result": pid})
                else:
                    send({"op": "failed", "result": f"unknown request {req['op']!r}"})
    except (BrokenPipeError, ConnectionResetError):  # the launcher is gone: as at end of file
        return


def _report_exits(send) -> None:  # noqa: ANN001
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        send({"op": "exited", "pid": pid, "code": os.waitstatus_to_exitcode(status)})


def _preload(policy: str, mission: str) -> str | None:
    """Load the policy and build the plan grid for every agent forked from now on; an error
    is only reported back (each agent then loads the files itself and says what is wrong)."""
    try:
        plmarl_sitl.deploy.agent.preload.preload(policy, mission)
    except Exception as exc:  # noqa: BLE001
        return f"{exc.__class__.__name__}: {exc}"
    finally:
        _share()
    return None


def _agent(req: dict, closing: tuple) -> None:
    """In the forked child: become `plmarl agent ARGV`, and exit with its code (never return
    into the server's loop)."""
    code = 1
    try:
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)  # an agent stops on Ctrl-C, as `plmarl agent`
        signal.set_wakeup_fd(-1)
        sel, sock, *fds = closing
        sel.close()
        sock.close()
        for fd in fds:
            os.close(fd)
        code = run_agent(req["argv"], req["log_path"], req["env"], req["name"], req["nice"], req["launcher"])
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:  # noqa: BLE001 - the agent's log says what, the exit code that it failed
        import traceback

        traceback.print_exc()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:  # noqa: BLE001, S110 - a closed stream has nothing left to say
                pass
        os._exit(code)


def run_agent(argv: list[str], log_path: str, env: dict[str, str], name: str, nice: int, launcher: int) -> int:
    """The agent: stdout/stderr to `log_path`, then `plmarl agent ARGV`; its exit code.
    It stops (SIGTERM) when process `launcher` exits, and when its server does."""
    agent_child_setup(nice)
    sigterm_when_gone(launcher)  # first, before anything slow (sitl/forked.py: Lifetime)
    if not _server_parent_is(launcher):
        # The launcher died before the pidfd was opened: its pid may name another process by now.
        os.kill(os.getpid(), signal.SIGTERM)
    set_process_name(name)  # the command line is the launcher's
    output_to(log_path, 0o644)
    os.environ.update(env)
    from plmarl_sitl.deploy.agent.program import main

    return main(argv)


def _server_parent_is(pid: int) -> bool:
    """Whether this agent's server is still the child of process `pid` (it is reparented
    once the launcher that started it is gone)."""
    try:
        return psutil.Process(os.getppid()).ppid() == pid
    except psutil.Error:
        return False


if __name__ == "__main__":  # the exec'd server: FD LAUNCHER_PID
    serve(socket.socket(fileno=int(sys.argv[1])), int(sys.argv[2]))
