"""Broker URLs: mqtt://HOST[:PORT] (1883 by default)."""

from __future__ import annotations

from urllib.parse import urlsplit

from plmarl_sitl.errors import UserError


def parse_broker_url(url: str) -> tuple[str, int]:
    parts = urlsplit(url if "://" in url else f"mqtt://{url}")
    if parts.scheme not in ("mqtt", "tcp"):
        raise UserError(f"broker URL {url!r}: scheme must be mqtt:// (got {parts.scheme!r})")
    if not parts.hostname:
        raise UserError(f"broker URL {url!r}: no host")
    try:
        port = parts.port or 1883
    except ValueError as exc:
        raise UserError(f"broker URL {url!r}: bad port") from exc
    return parts.hostname, port
