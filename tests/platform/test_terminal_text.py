"""What a hostile gateway's text does to the user's terminal: the CLI printed the strings of
its answers as they came, so an ESC in a model's description could retitle the window, move
the cursor over earlier lines or write the clipboard (OSC 52), and a bidi override could
reorder the rest of a line. Each now reaches the terminal as its escape; JSON output was
already escaped by ``json.dumps``. Each test fails on the code before the fix."""

from __future__ import annotations

import json
from typing import Any

import pytest
from typer.testing import CliRunner, Result

from drlaas.cli import app
from drlaas.commands.client.session import table, terminal_safe, terminal_text

from .test_hostile_gateway_client import Fake, fake  # noqa: F401 - the fixture

ESC_TITLE = "\x1b]0;pwned\x07"
CLIPBOARD = "\x1b]52;c;cm0gLXJmIH4=\x07"
OVERRIDE = "\u202e"
UNSAFE = (ESC_TITLE, CLIPBOARD, OVERRIDE, "\x9b", "\u2066", "\u2028")
HOSTILE = f"fine model{ESC_TITLE}{CLIPBOARD} by {OVERRIDE}evil\x9b2J\u2066\u2028"
CID = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"


def run(*args: str) -> Result:
    return CliRunner().invoke(app, list(args), env={"COLUMNS": "200"})


def model(i: int) -> dict[str, Any]:
    return {"id": i, "cid": CID, "owner": "0x" + "11" * 20, "domain": 0, "env": "3 agents",
            "reputation": 0.5, "owner_reputation": 0.5, "allocations": 0,
            "description": HOSTILE}


def assert_shown_escaped(out: str) -> None:
    for bad in UNSAFE:
        assert bad not in out, repr(out)
    assert "\\x1b]0;pwned\\x07" in out and "\\u202eevil" in out, out


def test_model_show_prints_a_hostile_description_escaped(fake: Fake) -> None:  # noqa: F811
    fake.routes["/api/models/7"] = lambda f, b: (200, model(7))
    res = run("model", "show", "7", "--gateway", fake.url)
    assert res.exit_code == 0, res.output
    assert_shown_escaped(res.output)


def test_model_list_prints_hostile_cells_escaped(fake: Fake) -> None:  # noqa: F811
    """A table cell: newlines and tabs are spaces too (a row stays one line)."""
    row = model(3) | {"owner": "two\nlines\tand " + OVERRIDE + ESC_TITLE}
    fake.routes["/api/models"] = lambda f, b: (200, {"data": [row], "count": 1})
    res = run("model", "list", "--gateway", fake.url)
    assert res.exit_code == 0, res.output
    assert OVERRIDE not in res.output and "\x1b" not in res.output, repr(res.output)
    assert "two lines and \\u202e" in res.output, res.output


def test_a_hostile_error_message_is_escaped(fake: Fake) -> None:  # noqa: F811
    fake.routes["/api/models/7"] = lambda f, b: (
        404, {"detail": {"rule": "not_found", "msg": HOSTILE}})
    res = run("model", "show", "7", "--gateway", fake.url)
    assert res.exit_code == 1, res.output
    assert_shown_escaped(res.output)


def test_json_output_was_and_stays_escaped(fake: Fake) -> None:  # noqa: F811
    fake.routes["/api/models/7"] = lambda f, b: (200, model(7))
    res = run("model", "show", "7", "--gateway", fake.url, "--json")
    assert res.exit_code == 0 and "\x1b" not in res.output and OVERRIDE not in res.output
    assert json.loads(res.output)["description"] == HOSTILE  # the data itself is unchanged


@pytest.mark.parametrize("text", ["plain", "زیرساخت\u200cها", "日本語 ✓", "tab\tand\nnewline",
                                  "emoji 👩\u200d💻"])
def test_text_a_terminal_shows_as_is_passes_unchanged(text: str) -> None:
    """Only what a terminal acts on is escaped: scripts, ZWNJ/ZWJ, newlines and tabs stay."""
    assert terminal_text(text) == text


def test_terminal_safe_reaches_keys_and_nested_values() -> None:
    doc = terminal_safe({"a\x1b": [{"b": "\u202ex"}, 3, None], "n": 1.5})
    assert doc == {"a\\x1b": [{"b": "\\u202ex"}, 3, None], "n": 1.5}
    assert "\x1b" not in table([{"c": "\x1b[2J"}], [("c", "C")])
