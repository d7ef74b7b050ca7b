"""Browser fixtures: a real uvicorn server on a free loopback port, and headless Debian Chromium
driven by Playwright for Python (the system browser: ``apt-get install chromium``; never
``playwright install``)."""

from __future__ import annotations

import os
import shutil
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.frontend.fake_api import ALICE, FakeState, make_fake_app

CHROMIUM = os.environ.get("DRLAAS_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
#: Set to a directory to save one screenshot per page (e.g. /tmp) for a visual check.
SCREENSHOTS = os.environ.get("DRLAAS_UI_SCREENSHOTS")


def chromium_missing() -> str | None:
    """Why the browser tests cannot run here, or None."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "Playwright for Python is not installed (pip install playwright)"
    if not (Path(CHROMIUM).is_file() and os.access(CHROMIUM, os.X_OK)) and not shutil.which(
        CHROMIUM
    ):
        return (
            f"no Chromium at {CHROMIUM}: install the Debian package "
            "(apt-get install -y chromium) or point DRLAAS_CHROMIUM at one"
        )
    return None


class LiveServer:
    """uvicorn serving ``app`` in a thread, on a socket bound before start (no port race)."""

    def __init__(self, app: Any) -> None:
        import uvicorn

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}"
        config = uvicorn.Config(app, log_level="warning", lifespan="on", access_log=False)
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(
            target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True
        )

    def __enter__(self) -> LiveServer:
        self.thread.start()
        deadline = time.monotonic() + 15
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError(f"uvicorn did not start on {self.url}")
            time.sleep(0.02)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=10)
        self.sock.close()


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    reason = chromium_missing()
    if reason:
        pytest.skip(reason)
    from playwright.sync_api import expect, sync_playwright

    # a page waiting on the real gateway's chain writes took over Playwright's 5 s default on
    # a loaded machine (CI beside a benchmark): a wait bound, never a timing assert
    expect.set_options(timeout=20_000)
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        yield b
        b.close()


class PageErrors(list):
    """Uncaught exceptions and console errors of one page (failed HTTP loads excluded: the
    tests provoke 401/404/422 answers on purpose)."""


@pytest.fixture
def page_factory(browser: Any) -> Iterator[Any]:
    contexts = []
    pages: list[tuple[Any, PageErrors]] = []

    def make() -> Any:
        ctx = browser.new_context(viewport={"width": 1280, "height": 900})
        contexts.append(ctx)
        page = ctx.new_page()
        page.set_default_timeout(8000)
        errors = PageErrors()
        page.on("pageerror", lambda exc: errors.append(f"pageerror: {exc}"))
        page.on(
            "console",
            lambda msg: (
                errors.append(f"console: {msg.text}")
                if msg.type == "error" and "Failed to load resource" not in msg.text
                else None
            ),
        )
        page.errors = errors
        pages.append((page, errors))
        return page

    yield make
    problems = [e for _, errors in pages for e in errors]
    for ctx in contexts:
        ctx.close()
    assert not problems, f"JavaScript errors in the page: {problems}"


@pytest.fixture
def page(page_factory: Any) -> Any:
    return page_factory()


def screenshot(page: Any, name: str) -> None:
    if SCREENSHOTS:
        Path(SCREENSHOTS).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(SCREENSHOTS) / f"drlaas-ui-{name}.png"), full_page=True)


# ------------------------------------------------------------------ the fake gateway


@pytest.fixture(scope="module")
def fake() -> Iterator[tuple[LiveServer, FakeState]]:
    """tests/frontend/fake_api.py served once per test module."""
    state = FakeState()
    with LiveServer(make_fake_app(state)) as server:
        yield server, state


@pytest.fixture
def server(fake: tuple[LiveServer, FakeState]) -> LiveServer:
    fake[1].reset()
    return fake[0]


@pytest.fixture
def state(fake: tuple[LiveServer, FakeState], server: LiveServer) -> FakeState:
    return fake[1]


def sign_in_as_alice(page: Any) -> None:
    from playwright.sync_api import expect

    page.select_option("#demo-user", label="alice")
    page.click("#demo-sign-in")
    expect(page.locator("#me .addr")).to_have_attribute("title", ALICE)
