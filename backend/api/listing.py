"""Fast JSON for list endpoints: serialise plain dicts once with pydantic-core's Rust encoder.

A route that returns a pydantic model is validated against its ``response_model`` again and
then encoded; for a page of 100 rows that is most of the request's CPU time. List routes build
the page from plain column rows (the shapes of their ``*Public`` models, which still document
the response in the OpenAPI) and return :func:`json_response`.
"""

from __future__ import annotations

from typing import Any

from fastapi.responses import Response
from pydantic_core import to_json


def json_response(content: Any, status_code: int = 200) -> Response:
    """``content`` (dicts, lists, str, int, float, None) as an application/json response."""
    return Response(to_json(content), status_code=status_code, media_type="application/json")
