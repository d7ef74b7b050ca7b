"""Settings: service selection from DRLAAS_* variables, and errors that name the variable."""

from __future__ import annotations

from pathlib import Path

import pytest

from backend.settings import EMBEDDED_CHAIN_ID, Settings, SettingsError, load_settings

GOOD_SECRET = "k3J9wq0Zb7X1nR5tLm2Vc8Hy4Pd6Gf0Ae3Ws9Qu1"


@pytest.fixture(autouse=True)
def _clean_env(monkeypatch: pytest.MonkeyPatch) -> None:
    import os

    for name in list(os.environ):
        if name.startswith("DRLAAS_"):
            monkeypatch.delenv(name)


def test_defaults_are_embedded_and_live_under_the_data_dir(tmp_path: Path) -> None:
    s = load_settings(data_dir=tmp_path / "d")
    data = (tmp_path / "d").resolve()
    assert s.chain_service.kind == "embedded"
    assert s.effective_chain_id == EMBEDDED_CHAIN_ID
    assert s.ipfs_service.kind == "embedded" and s.ipfs_service.url == str(data / "ipfs")
    assert s.broker_service.url == f"sqla+sqlite:///{data / 'broker.sqlite'}"
    assert s.database_url == f"sqlite:///{data / 'drlaas.sqlite'}"
    assert s.effective_confirmations == 0  # the embedded chain never reorganises


def test_relative_data_dir_becomes_absolute(monkeypatch: pytest.MonkeyPatch, tmp_path: Path):
    monkeypatch.chdir(tmp_path)
    s = load_settings(data_dir="rel")
    assert s.data_dir == tmp_path.resolve() / "rel"  # same SQLite files from any process' cwd


def test_real_services_from_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DRLAAS_CHAIN", "http://127.0.0.1:8545")
    monkeypatch.setenv("DRLAAS_CHAIN_ID", "31337")
    monkeypatch.setenv("DRLAAS_IPFS", "http://127.0.0.1:5001")
    monkeypatch.setenv("DRLAAS_BROKER", "redis://127.0.0.1:6379/0")
    monkeypatch.setenv("DRLAAS_DATABASE", "postgresql://postgres@127.0.0.1/test")
    monkeypatch.setenv("DRLAAS_CONFIRMATIONS", "3")
    s = load_settings()
    assert (s.chain_service.kind, s.chain_service.url) == ("rpc", "http://127.0.0.1:8545")
    assert s.effective_chain_id == 31337
    assert s.ipfs_service.kind == "rpc"
    assert s.broker_service.kind == "redis"
    # plain postgresql:// would need psycopg2; the URL is pinned to psycopg 3
    assert s.database_url == "postgresql+psycopg://postgres@127.0.0.1/test"
    assert s.effective_confirmations == 3


def test_rpc_chain_without_chain_id_leaves_it_to_the_node() -> None:
    assert load_settings(chain="https://node.example:8545").effective_chain_id is None


def test_embedded_ipfs_directory(tmp_path: Path) -> None:
    s = load_settings(ipfs=f"embedded:{tmp_path}/blocks")
    assert s.ipfs_service.kind == "embedded" and s.ipfs_service.url == f"{tmp_path}/blocks"


@pytest.mark.parametrize(
    ("env", "value"),
    [
        ("DRLAAS_CHAIN", "ftp://node:21"),
        ("DRLAAS_CHAIN", "embeded"),
        ("DRLAAS_IPFS", "embedded:"),
        ("DRLAAS_IPFS", "ipfs://x"),
        ("DRLAAS_BROKER", "kafka://127.0.0.1:9092"),
        ("DRLAAS_BROKER", "redis://"),
        ("DRLAAS_DATABASE", "mysql://root@localhost/x"),
        ("DRLAAS_TOKEN_TTL_S", "0"),
        ("DRLAAS_MODE", "prod"),
        ("DRLAAS_AUTH_DOMAIN", "https://gateway.example/"),
        ("DRLAAS_MAX_UPLOAD_BYTES", "-1"),
    ],
)
def test_bad_value_names_the_variable(monkeypatch: pytest.MonkeyPatch, env: str, value: str):
    monkeypatch.setenv(env, value)
    with pytest.raises(SettingsError) as err:
        load_settings()
    lines = str(err.value).splitlines()[1:]
    assert len(lines) == 1 and lines[0].strip().startswith(env), str(err.value)


def test_several_bad_values_are_all_reported(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DRLAAS_CHAIN", "nope")
    monkeypatch.setenv("DRLAAS_BROKER", "nope")
    with pytest.raises(SettingsError) as err:
        load_settings()
    assert "DRLAAS_CHAIN" in str(err.value) and "DRLAAS_BROKER" in str(err.value)


def test_data_dir_must_not_be_a_file(tmp_path: Path) -> None:
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(SettingsError, match="DRLAAS_DATA_DIR"):
        load_settings(data_dir=f)


def test_development_secret_is_random_per_process() -> None:
    a, b = load_settings(), load_settings()
    assert len(a.secret_bytes) >= 32 and a.secret_bytes != b.secret_bytes


@pytest.mark.parametrize(
    ("secret", "reason"),
    [
        (None, "required"),
        ("changethis", "placeholder"),
        ("Secret", "placeholder"),
        ("abc123" * 3, "at least 32"),
    ],
)
def test_production_rejects_missing_placeholder_or_short_secret(
    monkeypatch: pytest.MonkeyPatch, secret: str | None, reason: str
) -> None:
    monkeypatch.setenv("DRLAAS_MODE", "production")
    if secret is not None:
        monkeypatch.setenv("DRLAAS_TOKEN_SECRET", secret)
    with pytest.raises(SettingsError, match=f"DRLAAS_TOKEN_SECRET.*{reason}"):
        load_settings()


def test_production_accepts_a_real_secret_and_never_shows_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("DRLAAS_MODE", "production")
    monkeypatch.setenv("DRLAAS_TOKEN_SECRET", GOOD_SECRET)
    s = load_settings()
    assert s.secret_bytes == GOOD_SECRET.encode()
    assert not s.demo_keys_allowed
    assert GOOD_SECRET not in repr(s) and GOOD_SECRET not in str(s.model_dump())


def test_settings_are_immutable() -> None:
    s = Settings()
    with pytest.raises(Exception, match="frozen"):
        s.chain = "http://x:1"  # type: ignore[misc]
