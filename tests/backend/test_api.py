"""Gateway shell: health, OpenAPI, error shapes for routing failures and unexpected errors."""

from __future__ import annotations

from pathlib import Path

from alembic.script import ScriptDirectory
from fastapi.testclient import TestClient

from backend.api.main import API_PREFIX, create_app
from backend.db.engine import alembic_config
from backend.settings import Settings, load_settings

P = API_PREFIX


def test_health_reports_services_and_schema(settings: Settings) -> None:
    with TestClient(create_app(settings)) as c:
        r = c.get(f"{P}/health")
    assert r.status_code == 200
    body = r.json()
    assert body["status"] == "ok" and body["database"] == "ok"
    head = ScriptDirectory.from_config(alembic_config()).get_current_head()
    assert head is not None and body["schema_revision"] == head  # migrated on start
    assert body["services"] == {
        "chain": "embedded",
        "ipfs": "embedded",
        "broker": "embedded",
        "database": "sqlite",
    }
    assert (settings.data_dir / "drlaas.sqlite").exists()


def test_health_is_degraded_when_the_database_is_down(tmp_path: Path) -> None:
    s = load_settings(
        data_dir=tmp_path,
        database="postgresql+psycopg://nobody@127.0.0.1:1/none?connect_timeout=2",
        broker="redis://127.0.0.1:6379/0",
        migrate_on_start=False,
    )
    with TestClient(create_app(s)) as c:
        r = c.get(f"{P}/health")
    assert r.status_code == 503
    body = r.json()
    assert body["status"] == "degraded" and body["database"] == "unavailable"
    assert body["services"]["database"] == "postgresql" and body["services"]["broker"] == "redis"


def test_secrets_never_appear_in_health(tmp_path: Path) -> None:
    secret = "S" * 40
    s = load_settings(data_dir=tmp_path, mode="production", token_secret=secret)
    with TestClient(create_app(s)) as c:
        assert secret not in c.get(f"{P}/health").text
        assert secret not in c.get(f"{P}/openapi.json").text


def test_openapi_documents_routes_errors_and_bearer_auth(settings: Settings) -> None:
    with TestClient(create_app(settings)) as c:
        spec = c.get(f"{P}/openapi.json").json()
        assert c.get(f"{P}/docs").status_code == 200
    paths = spec["paths"]
    assert {f"{P}/health", f"{P}/auth/nonce", f"{P}/auth/token", f"{P}/auth/me"} <= set(paths)
    schemas = spec["components"]["schemas"]
    assert {"RuleErrorBody", "RuleFailure", "NoncePublic", "TokenPublic"} <= set(schemas)
    me = paths[f"{P}/auth/me"]["get"]
    assert me["security"] == [{"HTTPBearer": []}]
    assert me["responses"]["401"]["content"]["application/json"]["schema"]["$ref"].endswith(
        "/RuleErrorBody"
    )
    assert paths[f"{P}/auth/token"]["post"]["responses"].keys() >= {"200", "401", "422"}
    assert {t["name"] for t in spec["tags"]} == {"health", "auth"}


def test_every_operation_documents_the_statuses_of_the_layers_in_front(
    settings: Settings,
) -> None:
    """413 (body size), 422 (body depth or fields), 503 (load shedding) on every operation;
    400 (undecodable body) where FastAPI parses the body; each in the shape it is answered."""
    with TestClient(create_app(settings)) as c:
        spec = c.get(f"{P}/openapi.json").json()
        undecodable = c.post(
            f"{P}/auth/nonce", content=b"\xe9t\xe9", headers={"content-type": "application/json"}
        )
    assert undecodable.status_code == 400 and undecodable.json()["detail"]["rule"] == "bad_request"

    def schema_ref(op: dict, code: str) -> str:
        return op["responses"][code]["content"]["application/json"]["schema"].get("$ref", "")

    operations = [
        (f"{m.upper()} {p}", op) for p, item in spec["paths"].items() for m, op in item.items()
    ]
    assert len(operations) >= 30
    for label, op in operations:
        assert schema_ref(op, "413").endswith("/RuleErrorBody"), label
        assert schema_ref(op, "422").endswith("/UnprocessableBody"), label
        assert "503" in op["responses"], label
        reads_body = "requestBody" in op and label != "POST /rpc"  # /rpc answers in JSON-RPC
        assert ("400" in op["responses"]) == reads_body, label
        assert "x-raw-body" not in op, label
    health = spec["paths"][f"{P}/health"]["get"]["responses"]["503"]["content"]
    refs = {s["$ref"].rsplit("/", 1)[1] for s in health["application/json"]["schema"]["anyOf"]}
    assert refs == {"HealthPublic", "RuleErrorBody"}  # degraded, or shed


def test_routing_errors_use_the_rule_shape(settings: Settings) -> None:
    with TestClient(create_app(settings)) as c:
        r404 = c.get(f"{P}/no-such-thing")
        r405 = c.delete(f"{P}/health")
        bad_json = c.post(
            f"{P}/auth/nonce", content=b"{not json", headers={"content-type": "application/json"}
        )
    assert r404.status_code == 404 and r404.json()["detail"]["rule"] == "not_found"
    assert r405.status_code == 405 and r405.json()["detail"]["rule"] == "method_not_allowed"
    assert bad_json.status_code == 422
    assert bad_json.json()["detail"][0]["type"] == "json_invalid"


def test_unexpected_error_is_a_json_500_without_internals(settings: Settings) -> None:
    app = create_app(settings)

    @app.get("/boom")
    def boom() -> None:
        raise RuntimeError("secret internals")

    app.router.routes.insert(0, app.router.routes.pop())  # ahead of the web UI's catch-all mount

    with TestClient(app, raise_server_exceptions=False) as c:
        r = c.get("/boom")
    assert r.status_code == 500
    assert r.json() == {"detail": {"rule": "internal_error", "msg": "internal server error"}}
    assert "secret internals" not in r.text


def test_two_apps_in_one_process_keep_their_own_databases(tmp_path: Path) -> None:
    a = create_app(load_settings(data_dir=tmp_path / "a"))
    b = create_app(load_settings(data_dir=tmp_path / "b"))
    with TestClient(a), TestClient(b):
        pass
    assert (tmp_path / "a" / "drlaas.sqlite").exists() and (
        tmp_path / "b" / "drlaas.sqlite"
    ).exists()
    assert a.state.engine is not b.state.engine
