"""Who "one client" is for every per-client limit of the gateway: its network, not its address.

An IPv6 host is given a whole /64 (often a /56 or /48) and picks any address in it, so keying a
budget by the peer address made one host 2^64 clients, each with a full budget, and let it
evict everyone else's buckets. An IPv6 peer therefore counts as its ``client_ipv6_prefix``
network (``DRLAAS_CLIENT_IPV6_PREFIX``, default 64); an IPv4 peer as its address (an IPv4
address is scarce), also when it arrives IPv4-mapped (``::ffff:a.b.c.d``) on a dual-stack
socket. Every route that keys a budget by client goes through :func:`client_key`.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Mapping
from typing import Any

from backend.settings import Settings

UNKNOWN = "unknown"
"""The key of requests whose peer the server does not report (e.g. a Unix socket): all share it."""
DEFAULT_IPV6_PREFIX: int = Settings.model_fields["client_ipv6_prefix"].default


def client_key(connection: Mapping[str, Any]) -> str:
    """The per-client budget key of a request: a Starlette ``Request`` (a mapping over its ASGI
    scope) or the scope itself. The prefix length comes from the app's settings."""
    peer = connection.get("client")
    if not peer:
        return UNKNOWN
    app = connection.get("app")
    settings = getattr(getattr(app, "state", None), "settings", None)
    prefix = getattr(settings, "client_ipv6_prefix", DEFAULT_IPV6_PREFIX)
    return network_key(str(peer[0]), prefix)


def network_key(host: str, ipv6_prefix: int = DEFAULT_IPV6_PREFIX) -> str:
    """``host`` as a budget key: an IPv4 address itself, an IPv6 address its ``/ipv6_prefix``
    network (``2001:db8:1:2::/64``), an IPv4-mapped IPv6 address its IPv4 address. The IPv6
    loopback ``::1`` stays ``::1`` (this machine: the routes know it by that name). Anything
    that is not an IP address (a test client's name) is kept as it is."""
    try:
        address = ipaddress.ip_address(host.split("%", 1)[0])  # a zone ("fe80::1%eth0") is local
    except ValueError:
        return host
    if isinstance(address, ipaddress.IPv4Address):
        return str(address)
    if address.ipv4_mapped is not None:
        return str(address.ipv4_mapped)
    if address.is_loopback:
        return str(address)
    network = ipaddress.IPv6Network((address, ipv6_prefix), strict=False)
    return str(network)
