"""Schemathesis with every check over every operation of the gateway's OpenAPI document.

Each operation gets 50 schema-valid and 50 schema-invalid requests (derandomized: the same
requests on every run), sent to the in-process app on the embedded chain, signed in as a
registered requester and worker (an auth hook), so writes get past 401 to validation, the
chain and the indexer. Every built-in check runs: no 5xx, every status and body as documented,
schema-valid requests accepted and schema-invalid ones refused with a 4xx. Zero failures.

Narrow exceptions, each with its reason, are in ``CONFIG`` and ``UNSCHEMATIC_REJECTIONS``.
"""

from __future__ import annotations

import os
import re
from collections import defaultdict
from typing import Any

import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable

from backend.services.chain import ChainService

from .conftest import Login, P, register

schemathesis = pytest.importorskip("schemathesis")
from schemathesis.checks import CHECKS, load_all_checks  # noqa: E402
from schemathesis.config import SchemathesisConfig  # noqa: E402
from schemathesis.generation import GenerationMode  # noqa: E402

#: 20 per operation and mode in CI (about a minute); DRLAAS_SCHEMATHESIS_EXAMPLES=200 for a
#: deeper run by hand.
EXAMPLES_PER_OPERATION = int(os.environ.get("DRLAAS_SCHEMATHESIS_EXAMPLES", "20"))
#: What a schema-valid request may get besides 2xx: 402 insufficient_funds (a payment larger than
#: the caller's balance: state, not schema), 401/403/404/409 and the documented 422.
_SCHEMA_VALID_422 = '["2xx", "401", "402", "403", "404", "409", "422"]'
#: Per-operation changes to the checks' defaults (``include-name`` = one operation exactly).
#: * POST /rpc speaks JSON-RPC 2.0, which answers every request with HTTP 200, an invalid one
#:   with an ``error`` object (-32600 ...): its negative requests get 200 by the protocol. Its
#:   200 body is still checked against the declared response-or-error schema.
#: * The other five may refuse a schema-valid request with their documented 422: rules JSON
#:   Schema cannot state. Which rules, exactly, is ``UNSCHEMATIC_REJECTIONS``.
CONFIG = f"""
[[operations]]
include-name = "POST /rpc"
checks.negative_data_rejection.expected-statuses = ["200"]

[[operations]]
include-name = "POST /api/tasks"
checks.positive_data_acceptance.expected-statuses = {_SCHEMA_VALID_422}

[[operations]]
include-name = "POST /api/models"
checks.positive_data_acceptance.expected-statuses = {_SCHEMA_VALID_422}

[[operations]]
include-name = "POST /api/models/requests"
checks.positive_data_acceptance.expected-statuses = {_SCHEMA_VALID_422}

[[operations]]
include-name = "POST /api/tx"
checks.positive_data_acceptance.expected-statuses = {_SCHEMA_VALID_422}

[[operations]]
include-name = "POST /api/auth/token"
checks.positive_data_acceptance.expected-statuses = ["2xx", "401", "422"]
"""

_ENV_RELATIONS = (
    r"with min <= max",  # a [min, max] pair in order (walls, wall_length)
    r"uniform needs \[low, high\]",  # an intensity range in order
    r"at most \d+ walls",  # walls <= max(rows, cols)
    r"walls need a grid of at least 4x4",
    r"agents and a target do not fit",  # agents + 1 <= rows * cols
    r"of the wall layouts this spec allows leave an area",  # the layout fit probe (env.py)
    r"walls are at most \d+ cells long",  # wall_length within the grid
)
UNSCHEMATIC_REJECTIONS: dict[str, tuple[str, ...]] = {
    "POST /api/tasks": (
        *_ENV_RELATIONS,
        r"window must be < min\(rows, cols\)",
        r"^spec_exceeds_\w+$",  # resource limits: estimated memory, worker-hours
        r"^reward_below_minimum ",  # payment vs duration, minimum read from the chain
        r"^tasks_bad_duration$",  # deadline_s within the TMC's settings, read from the chain
        # experts (MEDC) and the walls CAE: model CIDs (the schema states the pattern) whose
        # bundles are in the store, or the caller's allocation in the index
        r"^(expert|walls_cae)_(not_found|invalid) ",
        r"^walls_cae_(grid|size)_mismatch ",
        r"^allocation_(not_found|empty) ",
        r"give experts or expert_allocation, not both",
        r"the QoS weights are all 0",  # a relation over the items (some qos > 0)
        # algorithm.demonstration (nested) needs experts or expert_allocation (top level)
        r"applies only when experts are named",
        r"needs budget\.steps",  # schedules over the step budget (anneal_lr, rate_end)
        # outcome_key: a point of secp256k1 whose address is the caller's (sealed outcomes)
        r"not a point of secp256k1",
        r"^outcome_key_not_requester ",
    ),
    "POST /api/models": (
        *_ENV_RELATIONS,
        r"^(bundle_not_found|card_missing|card_invalid|env_mismatch_card) ",  # the store
        # the bundle in the store is not a model the workers load (backend/api/bundles.py)
        r"^(bundle_\w+|card_format_invalid|weights_\w+) ",
    ),
    "POST /api/models/requests": (
        *_ENV_RELATIONS,
        r"must sum to 1e6",
        r"^price_below_minimum ",  # minimum price per model, read from the chain
    ),
    "POST /api/tx": (r"^tx_invalid$",),  # RLP and a recoverable signature
    "POST /api/auth/token": (r"^siwe_message_malformed$",),  # EIP-4361 grammar
}
"""What a schema-valid request may be refused for (422), by operation: relations between
fields, the state of the chain or the content store, the grammar of a signed message. Any other
reason means the OpenAPI document promised something the gateway does not accept."""


def _reasons(body: Any) -> list[str]:
    """``"<rule or type> <msg>"`` of each problem a 422 names (both documented shapes)."""
    detail = body.get("detail") if isinstance(body, dict) else None
    if isinstance(detail, dict):
        return [str(detail.get("rule"))]
    return [f"{issue.get('type')} {issue.get('msg')}" for issue in detail or []]


def only_unschematic_rejections(ctx: Any, response: Any, case: Any) -> None:
    """A schema-valid request refused with 422 names only a rule in UNSCHEMATIC_REJECTIONS."""
    if response.status_code != 422 or case.meta is None:
        return
    if not case.meta.generation.mode.is_positive:
        return
    allowed = UNSCHEMATIC_REJECTIONS.get(case.operation.label)
    if allowed is None:
        return  # positive_data_acceptance refuses any 422 there
    for reason in _reasons(response.json()):
        if not any(re.search(pattern, reason) for pattern in allowed):
            raise AssertionError(
                f"schema-valid request refused for a rule JSON Schema can state: {reason}"
            )


def test_every_operation_conforms_to_its_openapi_contract(
    client: TestClient, login: Login, service: ChainService
) -> None:
    register(client, login, ["user1"], {"user1": {}})
    token = login("user1")["Authorization"]
    load_all_checks()
    checks = [CHECKS.get_one(name) for name in CHECKS.get_all_names()]
    assert len(checks) >= 14  # every built-in check, not a chosen few
    checks.append(only_unschematic_rejections)
    config = SchemathesisConfig.from_str(CONFIG)
    schema = schemathesis.openapi.from_asgi(f"{P}/openapi.json", client.app, config=config)

    @schema.auth(refresh_interval=None)
    class SignedIn:
        """The bearer token of user1 on every operation (schemathesis still sends requests
        without it, or with a broken one, to check they get 401)."""

        def get(self, case: Any, context: Any) -> str:
            return token

        def set(self, case: Any, data: str, context: Any) -> None:
            case.headers = {**(case.headers or {}), "Authorization": data}

    failures: dict[tuple[str, str], list[str]] = defaultdict(list)
    labels = set()
    for result in schema.get_all_operations():
        operation = result.ok()
        labels.add(operation.label)
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):

            @given(case=operation.as_strategy(generation_mode=mode))
            @settings(
                max_examples=EXAMPLES_PER_OPERATION,
                deadline=None,
                suppress_health_check=list(HealthCheck),
                derandomize=True,
                database=None,
            )
            def run(case: Any) -> None:
                try:
                    case.call_and_validate(checks=checks)
                except BaseException as exc:  # noqa: BLE001 - collected, asserted below
                    for failure in getattr(exc, "exceptions", [exc]):
                        title = getattr(failure, "title", type(failure).__name__)
                        message = getattr(failure, "message", str(failure))
                        failures[(case.operation.label, title)].append(
                            f"{case.meta.generation.mode.value}: {message[:600]}\n"
                            f"{case.as_curl_command()[:600]}"
                        )

            try:
                run()
            except Unsatisfiable:  # nothing to make invalid (no parameters, no body)
                assert mode == GenerationMode.NEGATIVE
    documented = {
        f"{method.upper()} {path}"
        for path, item in client.get(f"{P}/openapi.json").json()["paths"].items()
        for method in item
    }
    assert labels == documented  # every operation, none skipped
    assert set(UNSCHEMATIC_REJECTIONS) <= labels
    report = "\n\n".join(
        f"== {label} | {title} ({len(seen)} requests)\n" + "\n--\n".join(seen[:3])
        for (label, title), seen in failures.items()
    )
    assert not failures, report
