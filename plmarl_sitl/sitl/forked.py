"""Agent processes forked from one server process that has already imported torch.

`import torch` costs ~1.2-2 s of CPU per process. Twenty agents exec'd at once on two cores
spend ~15 s of wall time importing the same modules before any vehicle flies. A swarm
launcher therefore keeps one *fork server* that imports the agent's modules once (and loads
the swarm's policy and plan grid: deploy/agent/preload.py), and forks each agent from it
(copy-on-write, ~20 ms each). Each child is still one asyncio process per UAV running
`plmarl agent` with the same arguments; only the interpreter start-up is shared. A companion
computer runs `plmarl agent` itself.

Where the server comes from (issue 25.1: the rig imported torch twice). `plmarl swarm up`
calls `start_server()` first thing: it imports torch in the launcher (whose world needs it
anyway) and then *forks* the server from the launcher, before the launcher has a thread or
an event loop (a fork with live threads can leave a lock held forever in the child). The
server then imports the agent-only modules itself, on the other core, while the launcher
imports the world's. One `import torch` for the whole rig, and the server holds no module of
the world's (each would be in every agent's RSS). A caller that already runs threads (a test,
`plmarl bench swarm`) gets the same server exec'd as a fresh interpreter instead
(`python -m plmarl_sitl.sitl.forked_child`): the old cost, and the same protocol.

The protocol: one SOCK_SEQPACKET socket pair, a JSON message each way per request
("preload", "fork"), answered in order; the server also reports each agent's exit status
("exited"), since it, not the launcher, is the agents' parent (the agents' side:
`sitl/forked_child.py`).

Lifetime: no agent outlives the launcher, even a SIGKILLed one. The server is the launcher's
child: it dies with it (PR_SET_PDEATHSIG) and exits when its socket reaches end of file (the
launcher closed it, or is gone). Each agent is the server's child and dies with it
(PR_SET_PDEATHSIG), and also watches the launcher through a pidfd (`proc.sigterm_when_gone`);
either way it gets SIGTERM, its normal stop (the vehicle to its stop mode, exit). Ctrl-C
reaches the whole process group: the server ignores it (the launcher stops the agents, then
closes the socket), the agents stop on it as `plmarl agent` does.
"""

from __future__ import annotations

import asyncio
import collections
import functools
import gc
import json
import os
import signal
import socket
import subprocess
import sys
import threading
from concurrent.futures import Future
from pathlib import Path

from plmarl_sitl.sitl.fork_protocol import MAX_MESSAGE, THREADS_ENV


def single_threaded() -> bool:
    """Whether this process runs one thread, native ones included (OpenBLAS starts its
    pool when numpy loads, unless OPENBLAS_NUM_THREADS=1), and no event loop: then a fork
    is safe."""
    try:
        asyncio.get_running_loop()
        return False
    except RuntimeError:
        pass
    try:
        return len(os.listdir("/proc/self/task")) == 1
    except OSError:  # no /proc: Python's own threads only
        return threading.active_count() == 1


class AgentServer:
    """The launcher's end of the fork server: requests out, answers and exit statuses in
    (a daemon thread reads them, so both a plain caller and an event loop can wait)."""

    def __init__(self, sock: socket.socket, pid: int, popen: subprocess.Popen | None = None) -> None:
        self.pid, self._sock, self._popen = pid, sock, popen
        # For the launcher's log: an exec'd server costs a second `import torch`.
        self.how = "exec'd (its launcher ran threads)" if popen is not None else "forked from its launcher"
        self._send_lock = threading.Lock()  # a request's place in `_pending` is its place on the wire
        self._pending: collections.deque[Future] = collections.deque()
        self.exits: dict[int, int] = {}  # agent pid -> exit code (-N: killed by signal N)
        self.gone = False
        self._reader = threading.Thread(target=self._read, name="fork-server-reader", daemon=True)
        self._reader.start()

    def request(self, op: str, **args: object) -> Future:
        """Send one request; its answer (the preload's error or None, a fork's pid; RuntimeError
        when the server could not fork) comes back on the returned future, in the order sent."""
        data = json.dumps({"op": op, **args}).encode()
        if len(data) > MAX_MESSAGE:
            raise ValueError(f"fork server request of {len(data)} bytes (at most {MAX_MESSAGE})")
        fut: Future = Future()
        with self._send_lock:
            if self.gone:
                raise RuntimeError("the agents' fork server has exited")
            self._pending.append(fut)
            self._sock.sendall(data)
        return fut

    def _read(self) -> None:
        while True:
            try:
                data = self._sock.recv(MAX_MESSAGE)
            except OSError:
                data = b""
            if not data:
                break
            msg = json.loads(data)
            if msg["op"] == "exited":
                self.exits[msg["pid"]] = msg["code"]
                continue
            fut = self._pending.popleft()  # (deque: atomic; no lock a blocked send holds)
            if msg["op"] == "failed":
                fut.set_exception(RuntimeError(msg["result"]))
            else:
                fut.set_result(msg["result"])
        with self._send_lock:
            self.gone = True
            pending, self._pending = list(self._pending), collections.deque()
        for fut in pending:
            fut.set_exception(RuntimeError("the agents' fork server has exited"))
        self._reap()

    def returncode(self, pid: int) -> int | None:
        """Agent `pid`'s exit code as its server reported it; None while it runs. With the
        server gone (killed), its agents got SIGTERM from the kernel (PR_SET_PDEATHSIG)."""
        code = self.exits.get(pid)
        if code is None and self.gone and not _exists(pid):
            return -signal.SIGTERM
        return code

    def close(self, timeout_s: float = 5.0) -> None:
        """End of file to the server (it exits; any agent still running gets SIGTERM), and
        wait for it."""
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._reader.join(timeout_s)
        self._sock.close()

    def _reap(self) -> None:
        if self._popen is not None:
            try:
                self._popen.wait(5.0)
            except subprocess.TimeoutExpired:
                self._popen.kill()
                self._popen.wait()
            return
        try:
            os.waitpid(self.pid, 0)
        except ChildProcessError:
            pass


def _exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


_server: AgentServer | None = None


def start_server() -> AgentServer:
    """The fork server, started now if it is not running: forked from this process when
    that is safe (one thread, no event loop; `plmarl swarm up` calls this first thing), else
    exec'd. Either way this process imports torch first: what a forked server shares."""
    global _server
    if _server is not None and not _server.gone:
        return _server
    for k, v in THREADS_ENV.items():
        os.environ.setdefault(k, v)
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    launcher = os.getpid()
    if single_threaded():
        # torch's import builds ~2e5 objects that live as long as the process: with the
        # collector off meanwhile and the result frozen, no full pass walks them as they pile
        # up (four passes, ~0.4 s of CPU in a scale_20 start-up), and the forked server
        # shares their pages untouched (what gc.freeze before a fork is for).
        gc.disable()
        try:
            import torch  # noqa: F401 - imported once, here, for this process and the server
        finally:
            gc.enable()
        gc.freeze()

        pid = os.fork()
        if pid == 0:  # the server; it never returns into the launcher's code
            code = 1
            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C during its imports: the launcher's to handle
                from plmarl_sitl.proc import die_with_parent

                die_with_parent()  # before the agent's imports: a launcher that fails at once takes it along
                ours.close()
                from plmarl_sitl.sitl.forked_child import serve

                serve(theirs, launcher)
                code = 0
            except BaseException:  # noqa: BLE001 - said on stderr, then the exit code says it
                import traceback

                traceback.print_exc()
            finally:
                os._exit(code)
        theirs.close()
        _server = AgentServer(ours, pid)
    else:
        popen = subprocess.Popen([sys.executable, "-m", "plmarl_sitl.sitl.forked_child", str(theirs.fileno()), str(launcher)],
                                 pass_fds=[theirs.fileno()], stdin=subprocess.DEVNULL, env=dict(os.environ, **THREADS_ENV))
        theirs.close()
        _server = AgentServer(ours, popen.pid, popen)
    return _server


def stop_server() -> None:
    """Close the fork server (at the launcher's end; every agent has been stopped)."""
    global _server
    if _server is not None:
        _server.close()
        _server = None


def warm_up(policy: str | os.PathLike | None = None, mission: str | os.PathLike | None = None) -> None:
    """Start the fork server if it is not running; with `policy` and `mission`, have it
    load that policy and build its plan grid now, once for every agent it forks
    (deploy/agent/preload.py), while the caller starts the broker and the world. What a
    server loaded before stays (keyed by the files' versions)."""
    server = start_server()
    if policy is not None and mission is not None:
        server.request("preload", policy=str(Path(policy)), mission=str(Path(mission)))


class ForkedProcess:
    """The part of `asyncio.subprocess.Process` the fleet uses, for a forked agent."""

    def __init__(self, server: AgentServer, pid: int) -> None:
        self._server = server
        self.pid = pid

    @property
    def returncode(self) -> int | None:
        """Exit code, or -signal when a signal killed it (as asyncio reports it)."""
        return self._server.returncode(self.pid)

    async def wait(self) -> int:
        while (code := self.returncode) is None:
            await asyncio.sleep(0.05)
        return code

    def send_signal(self, sig: int) -> None:
        if self.returncode is None:
            os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


async def fork_agent(argv: list[str], log_path: str, env: dict[str, str], name: str, nice: int = 0) -> ForkedProcess:
    """Fork `plmarl agent ARGV` from the fork server (started now if it is not running). `name`
    (e.g. plmarl-agent3) is what ps, top and psutil's name() show for it; `nice` is added to
    its niceness; its stdout and stderr go to `log_path`; `env` is added to its environment."""
    server = start_server()  # in the caller's thread: PR_SET_PDEATHSIG follows the thread that forks
    # Sent from a worker thread: a hundred requests can fill the socket while the server loads
    # the policy, and this loop keeps serving the vehicles meanwhile.
    fut = await asyncio.get_running_loop().run_in_executor(None, functools.partial(
        server.request, "fork", argv=argv, log_path=log_path, env=env, name=name, nice=nice, launcher=os.getpid()))
    pid = await asyncio.wrap_future(fut)
    return ForkedProcess(server, pid)
