"""The signalling messages as they go on the wire: signed under the swarm key, or not.

`Wire(key)` encodes and decodes every message an agent or the world exchanges. With a key
(schema version 2, docs/SIGNALLING.md) each binary message carries version byte 2 and
each JSON message `"v": 2`, followed by the authentication trailer of `auth.py`;
decoding checks the trailer first and raises `AuthError` (unsigned, wrong key, forged)
before the message is read. `Wire(None)` is the unsigned version-1 wire (a swarm run
with `--no-auth`, and unit tests of the layers above). Decoders raise only `Malformed`
or `AuthError`; callers count both by reason.
"""

from __future__ import annotations

from plmarl_sitl.deploy.mqtt.auth import TRAILER_BYTES, AuthError, SwarmKey
from plmarl_sitl.deploy.mqtt.demand import DemandMsg, decode_demand, encode_demand
from plmarl_sitl.deploy.mqtt.schema import (
    SIGNED_VERSION,
    STATE_SIZE,
    VERSION,
    Malformed,
    SenseMsg,
    StateMsg,
    decode_json,
    decode_sense,
    decode_state,
    encode_json,
    encode_sense,
    encode_state,
    split_states,
)

STATE, SENSE, DEMAND = b"S", b"U", b"D"  # the authentication domains of the binary messages


class Wire:
    def __init__(self, key: SwarmKey | None) -> None:
        self.key = key
        self.state_size = STATE_SIZE + (TRAILER_BYTES if key is not None else 0)

    @property
    def signed(self) -> bool:
        return self.key is not None

    # ------------------------------------------------------------------ binary messages
    def _seal(self, domain: bytes, message: bytes) -> bytes:
        if self.key is None:
            return message
        return self.key.seal(domain, bytes((SIGNED_VERSION,)) + message[1:])

    def _open(self, domain: bytes, payload: bytes) -> bytes:
        """The version-1 message inside a signed payload (unsigned wire: the payload)."""
        if self.key is None:
            return payload
        if payload[:1] == bytes((VERSION,)):
            raise AuthError("unsigned")
        message = self.key.open(domain, payload)
        if message[0] != SIGNED_VERSION:
            raise Malformed("version")
        return bytes((VERSION,)) + message[1:]

    def state(self, m: StateMsg) -> bytes:
        return self._seal(STATE, encode_state(m))

    def split_states(self, payload: bytes) -> list[bytes]:
        return split_states(payload, self.state_size - STATE_SIZE)

    def read_state(self, part: bytes) -> StateMsg:
        return decode_state(self._open(STATE, part))

    def sense(self, receiver: int, t_ms: int, users_ne: object) -> bytes:
        return self._seal(SENSE, encode_sense(receiver, t_ms, users_ne))

    def read_sense(self, payload: bytes) -> SenseMsg:
        return decode_sense(self._open(SENSE, payload))

    def demand(self, map_seq: int, t_ms: int, cell_m: float, rows: int, cols: int, counts: object) -> bytes:
        return self._seal(DEMAND, encode_demand(map_seq, t_ms, cell_m, rows, cols, counts))

    def read_demand(self, payload: bytes) -> DemandMsg:
        return decode_demand(self._open(DEMAND, payload))

    # ------------------------------------------------------------------ JSON messages
    def json(self, domain: str, obj: dict) -> bytes:
        """A JSON message of class `domain` ("start", "ctl", "closed")."""
        if self.key is None:
            return encode_json(obj)
        return self.key.seal(domain.encode(), encode_json(obj, SIGNED_VERSION))

    def read_json(self, domain: str, payload: bytes) -> dict:
        if self.key is None:
            return decode_json(payload)
        try:
            message = self.key.open(domain.encode(), payload)
        except AuthError as refused:
            if _is_plain_json(payload):
                raise AuthError("unsigned") from None
            raise refused from None
        return decode_json(message, SIGNED_VERSION)


def _is_plain_json(payload: bytes) -> bool:
    """A version-1 JSON message (no trailer)?"""
    try:
        decode_json(payload)
    except Malformed:
        return False
    return True
