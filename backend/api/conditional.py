"""``If-None-Match`` on content addressed by CID (RFC 9110, 13.1.2 and 15.4.5).

A block or bundle file served under ``ETag: "<cid>"`` can never change: a client that holds it
(a browser cache, ``drlaas model pull`` resuming) asks with ``If-None-Match`` and gets 304 Not
Modified, no body, instead of the same bytes again.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from fastapi import Request
from fastapi.responses import Response

#: One entity-tag, weak or strong (RFC 9110, 8.8.3): ``W/"..."`` or ``"..."``; the opaque part
#: holds no DQUOTE, so a comma inside it is part of the tag, not a list separator.
_ENTITY_TAG = re.compile(r'(?:W/)?"([^"]*)"')
#: Headers a 304 carries (RFC 9110, 15.4.5: those a 200 would have sent that describe caching).
_NOT_MODIFIED_HEADERS = ("etag", "cache-control", "content-location", "date", "expires", "vary")


def _opaque_tags(value: str) -> list[str] | None:
    """The opaque parts of a comma-separated list of entity-tags (weak or strong), ``None`` for
    ``*``. A malformed member ends the list: what follows cannot be told apart from it."""
    if value.strip() == "*":
        return None
    tags: list[str] = []
    pos, end = 0, len(value)
    while pos < end:
        while pos < end and value[pos] in " \t,":  # OWS and empty list elements
            pos += 1
        if pos == end:
            break
        found = _ENTITY_TAG.match(value, pos)
        if found is None:
            break
        tags.append(found.group(1))
        pos = found.end()
        while pos < end and value[pos] in " \t":
            pos += 1
        if pos < end and value[pos] != ",":
            break
    return tags


def none_match(request: Request, etag: str) -> bool:
    """Whether ``If-None-Match`` of ``request`` matches the strong entity-tag ``etag``
    (``"<cid>"``): ``*``, or a listed tag weakly equal to it (If-None-Match compares weakly, so
    ``W/"<cid>"`` matches too). Several header lines are one list."""
    lines = request.headers.getlist("if-none-match")
    if not lines:
        return False
    tags = _opaque_tags(",".join(lines))
    if tags is None:
        return True
    opaque = etag.removeprefix("W/").strip('"')
    return opaque in tags


def not_modified(headers: Mapping[str, str]) -> Response:
    """A 304 with the caching headers of the 200 it replaces (``headers``), no body and no
    ``Content-Length``/``Content-Type`` (they describe a body that is not sent)."""
    kept = {k: v for k, v in headers.items() if k.lower() in _NOT_MODIFIED_HEADERS}
    return Response(status_code=304, headers=kept)
