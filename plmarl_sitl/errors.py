"""The toolkit's error tree (public fields, causes chained with `from`) and `run_reporting`,
which turns every failure a user can cause or meet into one line on stderr and an exit code."""

from __future__ import annotations

import sys
from collections.abc import Callable

# Exit codes of every program (`plmarl ...`, the agent run without the CLI).
EXIT_USER = 2  # something the user gave is wrong (a flag, a file, a mission that does not fit the vehicle)
EXIT_VEHICLE = 3  # the vehicle refused, went silent or its link broke
EXIT_SYSTEM = 1  # the operating system refused (a port in use, a permission)
EXIT_INTERRUPTED = 130  # Ctrl-C


class PlmarlError(Exception):
    """Base of every error the toolkit raises on purpose."""


class UserError(PlmarlError):
    """Something the user gave is wrong (a flag, a file); the message says what to fix."""


class CommandRejected(PlmarlError):
    """A vehicle answered a MAVLink command with a COMMAND_ACK other than ACCEPTED.

    `result` is the MAV_RESULT number and `result_name` its name, so callers can tell a
    transient refusal (TEMPORARILY_REJECTED) from a permanent one (DENIED, UNSUPPORTED).
    """

    def __init__(self, sysid: int, command: int, result: int, result_name: str = "", command_name: str = "") -> None:
        self.sysid = sysid
        self.command = command
        self.result = result
        self.result_name = result_name or str(result)
        named = f"{command_name} ({command})" if command_name else str(command)
        super().__init__(f"vehicle {sysid}: command {named} rejected ({self.result_name})")


class VehicleUnreachable(PlmarlError):
    """Nothing came from a vehicle: it did not answer in time (VehicleTimeout) or its link
    broke (LinkLost). Catch this where both end the same way (a flight that loses its
    vehicle, a best-effort stop); catch one of them where they differ (a timeout retried or
    turned into advice, a lost link passed on at once)."""

    def __init__(self, sysid: int, message: str) -> None:
        self.sysid = sysid
        super().__init__(message)


class VehicleTimeout(VehicleUnreachable):
    """A vehicle did not answer in time (`what` says what we waited for)."""

    def __init__(self, sysid: int, what: str, timeout_s: float) -> None:
        self.what = what
        self.timeout_s = timeout_s
        super().__init__(sysid, f"vehicle {sysid}: no {what} within {timeout_s:g} s")


class LinkLost(VehicleUnreachable):
    """The link to a vehicle broke (a serial radio unplugged, a TCP connection closed):
    nothing more will come, so every wait on it ends at once instead of at its timeout.
    Not a VehicleTimeout: code that retries or explains a timeout must not retry a dead
    link; `reason` says which link and why."""

    def __init__(self, sysid: int, reason: str) -> None:
        self.reason = reason
        super().__init__(sysid, f"vehicle {sysid}: link lost ({reason})")


class VehicleLost(PlmarlError):
    """A flying vehicle went silent or its link broke: the agent can no longer fly it."""

    def __init__(self, cause: VehicleUnreachable) -> None:
        self.sysid = cause.sysid
        super().__init__(f"vehicle lost: {cause}")


class PolicyFileError(UserError):
    """A policy file (predictor.pt, policy.pt, card.yaml) is missing, corrupt or mismatched."""

    def __init__(self, path: str, problem: str) -> None:
        self.path = path
        self.problem = " ".join(problem.split())  # one line (a YAML parser's message spans several)
        super().__init__(f"{path}: {self.problem}")


def reported(exc: BaseException) -> BaseException:
    """The exception to report for `exc`: a task group's error is the first one its tasks
    raised (an asyncio.TaskGroup wraps even a single failure in an ExceptionGroup)."""
    while isinstance(exc, BaseExceptionGroup):
        exc = exc.exceptions[0]
    return exc


def exit_code(exc: BaseException) -> int | None:
    """The exit code for a failure a user can cause or meet; None for anything else (a bug,
    which keeps its traceback)."""
    if isinstance(exc, KeyboardInterrupt):
        return EXIT_INTERRUPTED
    if isinstance(exc, UserError):
        return EXIT_USER
    if isinstance(exc, PlmarlError):
        return EXIT_VEHICLE
    if isinstance(exc, OSError):
        return EXIT_SYSTEM
    return None


def run_reporting(prog: str, body: Callable[[], int | None]) -> int:
    """Run a program's body and return its exit code; a user-facing failure prints
    `PROG: error: MESSAGE` (or `PROG: interrupted`) on stderr instead of a traceback."""
    try:
        return int(body() or 0)
    except BaseException as raised:  # noqa: BLE001 - sorted below; anything unknown is re-raised
        exc = reported(raised)
        code = exit_code(exc)
        if code is None:
            raise
        if code == EXIT_INTERRUPTED:
            print(f"{prog}: interrupted", file=sys.stderr)
        else:
            print(f"{prog}: error: {exc}", file=sys.stderr)
        return code
