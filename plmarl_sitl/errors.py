"""The toolkit's error tree. Public fields, causes chained with `from`."""

from __future__ import annotations


class PlmarlError(Exception):
    """Base of every error the toolkit raises on purpose."""


class UserError(PlmarlError):
    """Something the user gave is wrong (a flag, a file); the message says what to fix."""


class CommandRejected(PlmarlError):
    """A vehicle answered a MAVLink command with a COMMAND_ACK other than ACCEPTED.

    `result` is the MAV_RESULT number and `result_name` its name, so callers can tell a
    transient refusal (TEMPORARILY_REJECTED) from a permanent one (DENIED, UNSUPPORTED).
    """

    def __init__(self, sysid: int, command: int, result: int, result_name: str = "") -> None:
        self.sysid = sysid
        self.command = command
        self.result = result
        self.result_name = result_name or str(result)
        super().__init__(f"vehicle {sysid}: command {command} rejected ({self.result_name})")


class VehicleTimeout(PlmarlError):
    """A vehicle did not answer in time (`what` says what we waited for)."""

    def __init__(self, sysid: int, what: str, timeout_s: float) -> None:
        self.sysid = sysid
        self.what = what
        self.timeout_s = timeout_s
        super().__init__(f"vehicle {sysid}: no {what} within {timeout_s:g} s")


class LinkLost(VehicleTimeout):
    """The link to a vehicle broke (a serial radio unplugged): nothing more will come, so
    every wait on it ends at once instead of at its timeout. A VehicleTimeout, so code that
    handles a silent vehicle handles this one too; `reason` says which link and why."""

    def __init__(self, sysid: int, reason: str) -> None:
        super().__init__(sysid, "message: link lost", 0.0)
        self.reason = reason
        self.args = (f"vehicle {sysid}: link lost ({reason})",)


class PolicyFileError(UserError):
    """A policy file (predictor.pt, policy.pt, card.yaml) is missing, corrupt or mismatched."""

    def __init__(self, path: str, problem: str) -> None:
        self.path = path
        self.problem = problem
        super().__init__(f"{path}: {problem}")
