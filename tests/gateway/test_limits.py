"""Request bodies are size- and depth-bounded before parsing, on every route, against a real
HTTP gateway; and the interpreter's recursion limit is the normal one after py-evm is loaded.

The issue this guards: a 200 KB body nested 100,000 deep on the sign-in nonce endpoint
segfaulted the gateway (py-evm/py_ecc had raised the recursion limit to 100,000), taking the
embedded chain with it.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from backend.api.limits import json_depth_exceeds
from backend.chain.client import Chain
from backend.chain.pyevm import NORMAL_RECURSION_LIMIT
from backend.settings import Settings

REPO = Path(__file__).resolve().parents[2]
DEEP = b"[" * 100_000 + b"]" * 100_000
JSON = {"Content-Type": "application/json"}


@pytest.mark.parametrize("path", ["/api/auth/nonce", "/rpc", "/api/tx", "/api/tasks"])
def test_deep_body_is_refused_and_the_gateway_stays_up(gateway: str, path: str) -> None:
    r = httpx.post(gateway + path, content=DEEP, headers=JSON, timeout=30)
    assert r.status_code == 422
    assert r.json()["detail"]["rule"] == "json_too_deep"
    health = httpx.get(gateway + "/api/health")
    assert health.status_code == 200
    # and it still serves the route the body was aimed at
    ok = httpx.post(gateway + "/rpc", json={"jsonrpc": "2.0", "id": 1, "method": "eth_chainId"})
    assert ok.json()["result"].startswith("0x")


def test_deep_object_in_an_object_is_refused(gateway: str) -> None:
    body = b'{"address":' + b'{"a":' * 70_000 + b"1" + b"}" * 70_001
    r = httpx.post(gateway + "/api/auth/nonce", content=body, headers=JSON, timeout=30)
    assert (r.status_code, r.json()["detail"]["rule"]) == (422, "json_too_deep")


def test_brackets_inside_strings_do_not_count(gateway: str) -> None:
    """100,000 brackets inside a string (with escaped quotes) reach the route, whose own
    validation answers: the scan honours strings and escapes."""
    body = b'{"address": "\\"' + b"[" * 100_000 + b'\\""}'
    r = httpx.post(gateway + "/api/auth/nonce", content=body, headers=JSON, timeout=30)
    assert r.status_code == 422
    assert isinstance(r.json()["detail"], list)  # field validation, not json_too_deep
    assert r.json()["detail"][0]["loc"][-1] == "address"


@pytest.mark.parametrize("path", ["/api/auth/nonce", "/rpc", "/api/tasks"])
def test_a_number_of_5000_digits_is_refused_by_name(gateway: str, path: str) -> None:
    """Python's JSON parser stops at 4,300 digits with a bare 400 'error parsing the body'."""
    body = b'{"address": "0x7E5F4552091A69125d5DfCb7b8C2659029395Bdf", "n": ' + b"7" * 5000 + b"}"
    r = httpx.post(gateway + path, content=body, headers=JSON, timeout=30)
    assert (r.status_code, r.json()["detail"]["rule"]) == (422, "json_number_too_long")


def test_long_digit_runs_inside_strings_and_uint256_numbers_pass(gateway: str) -> None:
    body = b'{"address": "' + b"7" * 5000 + b'", "n": ' + str(2**256 - 1).encode() + b"}"
    r = httpx.post(gateway + "/api/auth/nonce", content=body, headers=JSON, timeout=30)
    assert r.status_code == 422 and isinstance(r.json()["detail"], list)  # the field's own check
    assert "address" in r.text


def test_body_at_the_depth_limit_is_parsed(gateway: str) -> None:
    limit = Settings().max_json_depth
    params = "[" * (limit - 2) + "]" * (limit - 2)  # request object + params list + nesting
    body = '{"jsonrpc": "2.0", "id": 1, "method": "eth_blockNumber", "params": [' + params + "]}"
    r = httpx.post(gateway + "/rpc", content=body, headers=JSON)
    assert r.status_code == 200
    assert r.json()["error"]["code"] == -32602  # parsed, then refused: eth_blockNumber takes 0


def test_oversized_body_is_refused_by_declared_length(gateway: str) -> None:
    size = Settings().max_request_bytes + 1
    r = httpx.post(gateway + "/rpc", content=b" " * size, headers=JSON, timeout=30)
    assert r.status_code == 413
    assert r.json()["detail"]["rule"] == "payload_too_large"
    assert httpx.get(gateway + "/api/health").status_code == 200


def test_oversized_body_is_refused_while_streaming(gateway: str) -> None:
    """No Content-Length (chunked): counted while read, refused once past the limit."""
    limit = Settings().max_request_bytes

    def chunks() -> Iterator[bytes]:
        for _ in range(limit // 65_536 + 2):
            yield b" " * 65_536

    r = httpx.post(gateway + "/api/auth/nonce", content=chunks(), headers=JSON, timeout=30)
    assert r.status_code == 413
    assert r.json()["detail"]["rule"] == "payload_too_large"
    assert httpx.get(gateway + "/api/health").status_code == 200


@pytest.mark.parametrize(
    ("body", "limit", "deeper"),
    [
        (b"[[[]]]", 3, False),
        (b"[[[[]]]]", 3, True),
        (b'{"a": [{"b": []}]}', 4, False),
        (b'{"a": [{"b": [[]]}]}', 4, True),
        (b'["[[[[[[", "]]]"]', 1, False),  # brackets inside strings
        (b'["\\"[[[[", "\\\\", [[]]]', 2, True),  # escaped quote, escaped backslash, then depth 3
        (b'["\\\\"', 0, True),  # the string closes after an escaped backslash: depth 1 left open
        (b'"unterminated [[[[[', 0, False),  # an unterminated string swallows the rest
        (b"[ [\n[\t[", 3, True),  # not JSON (unclosed, whitespace): still counted
        (b"", 0, False),
    ],
)
def test_json_depth_scan(body: bytes, limit: int, deeper: bool) -> None:
    assert json_depth_exceeds(body, limit) is deeper


def test_recursion_limit_is_normal_after_the_embedded_chain() -> None:
    Chain.embedded(accounts=1)
    assert sys.getrecursionlimit() == NORMAL_RECURSION_LIMIT


def test_recursion_limit_is_restored_in_a_fresh_gateway_process(tmp_path: Path) -> None:
    """In a new interpreter (nothing imported yet): the gateway app and an embedded chain
    leave the limit where Python started it, although eth_account and py-evm raise it."""
    code = (
        "import sys; start = sys.getrecursionlimit()\n"
        "import eth_account; raised = sys.getrecursionlimit()\n"
        "from backend.api.main import create_app\n"
        "from backend.chain.client import Chain\n"
        "create_app(); Chain.embedded(accounts=1)\n"
        "print(start, raised, sys.getrecursionlimit())\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin", "DRLAAS_DATA_DIR": str(tmp_path)},
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    start, raised, after = map(int, out.stdout.split())
    assert raised > start  # the dependency really raises it (else this test proves nothing)
    assert after == start == NORMAL_RECURSION_LIMIT


def test_a_422_does_not_echo_a_huge_input(client, login) -> None:  # type: ignore[no-untyped-def]
    """A bad value of half a megabyte is named, not sent back: messages and locations are
    bounded (a key of the same size too)."""
    from tests.gateway.conftest import task_body

    huge = "k" * 500_000
    body = task_body()
    body["observation"] = {**body.get("observation", {}), "kind": huge}
    r = client.post("/api/tasks", json=body, headers=login("user1"))
    assert r.status_code == 422 and len(r.content) < 10_000, len(r.content)
    body = task_body()
    body["env"] = {**body["env"], huge: 1}
    r = client.post("/api/tasks", json=body, headers=login("user1"))
    assert r.status_code == 422 and len(r.content) < 10_000, len(r.content)
    assert "characters in all" in r.text
