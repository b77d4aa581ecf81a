"""The one rule for a Zenoh endpoint written by a user (``drovisio station --listen`` and
``--connect``, ``--sink zenoh:connect=...&listen=...``): ``PROTOCOL/HOST:PORT``.

Kept apart from the Zenoh sink so that the command line can check an endpoint without
loading the sink and its transport.
"""

from __future__ import annotations

import re

__all__ = ["ENDPOINT_HELP", "endpoint_problem"]

ENDPOINT_HELP = "write a Zenoh endpoint as tcp/HOST:PORT, e.g. tcp/0.0.0.0:7447"
"""How to write one, for the one-line refusal."""

_ENDPOINT = re.compile(r"(tcp|udp|tls|quic|ws)/[A-Za-z0-9.\-\[\]:]{1,200}:([0-9]{1,5})")


def endpoint_problem(text: str) -> str | None:
    """Why ``text`` is no Zenoh endpoint, in a few words, or None when it is one.

    Args:
        text: ``PROTOCOL/HOST:PORT``; protocol tcp, udp, tls, quic or ws; a host name, an
            IPv4 address or a bracketed IPv6 address; port 1-65535.
    """
    m = _ENDPOINT.fullmatch(text)
    if m is None:
        return "is not a Zenoh endpoint"
    if not 0 < int(m[2]) < 65536:
        return f"port {int(m[2])} is not in 1..65535"
    return None
