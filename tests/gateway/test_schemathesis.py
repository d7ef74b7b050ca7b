"""Property-based run over the OpenAPI document (schemathesis): a few generated requests per
operation, authenticated as a registered demo user; no request may produce a 5xx."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings

from backend.services.chain import ChainService

from .conftest import Login, P, register

schemathesis = pytest.importorskip("schemathesis")
EXAMPLES_PER_OPERATION = 10


def test_no_server_errors_on_generated_requests(
    client: TestClient, login: Login, service: ChainService
) -> None:
    # Generated requests act as a registered requester that is also a worker, so write
    # endpoints get past auth to validation, the chain (typed reverts) and the indexer.
    register(client, login, ["user1"], {"user1": {}})
    headers = login("user1")
    schema = schemathesis.openapi.from_asgi(f"{P}/openapi.json", client.app)
    failures: list[str] = []
    operations = 0
    for result in schema.get_all_operations():
        operation = result.ok()
        operations += 1

        @given(case=operation.as_strategy())
        @settings(
            max_examples=EXAMPLES_PER_OPERATION,
            deadline=None,
            suppress_health_check=list(HealthCheck),
            derandomize=True,
            database=None,
        )
        def run(case: object) -> None:
            response = case.call(headers=headers)  # type: ignore[attr-defined]
            if response.status_code >= 500:
                failures.append(
                    f"{case.method} {case.formatted_path} -> {response.status_code}: "  # type: ignore[attr-defined]
                    f"{response.text[:300]}"
                )

        run()
    assert operations >= 20  # every router is in the document
    assert failures == []
