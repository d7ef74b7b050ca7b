"""The task form takes its bounds from the OpenAPI document the gateway serves (the real app's,
tests/frontend/fake_api.py): the inputs carry them, a value past one is refused on its field
before anything is sent, a changed document changes the form, and without the document the
gateway's 422 still lands on the field."""

from __future__ import annotations

from decimal import Decimal
from typing import Any

import httpx
import pytest

from tests.frontend.conftest import LiveServer, sign_in_as_alice
from tests.frontend.fake_api import FakeState
from workers.mdrl.trainingspec import MAX_AGENTS, MAX_GRID

expect = pytest.importorskip("playwright.sync_api", reason="pip install playwright").expect

#: form input id -> path of its value in the request body ("[]" = the array's items)
INPUTS = {
    "#f-env-agents": "env.agents",
    "#f-env-rows": "env.rows",
    "#f-env-cols": "env.cols",
    "#f-env-walls_min": "env.walls.[]",
    "#f-env-walls_max": "env.walls.[]",
    "#f-observation-window": "observation.window",
    "#f-budget-steps": "budget.steps",
    "#f-budget-minutes": "budget.minutes",
    "#f-seed": "seed",
    "#f-domain": "domain",
    "#f-num_workers": "num_workers",
    "#f-min_reputation": "min_reputation",
    "#f-min_rating": "min_rating",
    "#f-min_cpu_cores": "min_cpu_cores",
    "#f-min_ram_gb": "min_ram_gb",
    "#f-deadline_s": "deadline_s",
}


def body_schema(doc: dict[str, Any]) -> dict[str, Any]:
    """The POST /api/tasks body schema of an OpenAPI document ($ref resolved)."""
    ref = doc["paths"]["/api/tasks"]["post"]["requestBody"]["content"]["application/json"]
    name = ref["schema"]["$ref"].removeprefix("#/components/schemas/")
    return doc["components"]["schemas"][name]


def prop(doc: dict[str, Any], path: str) -> dict[str, Any]:
    """The schema of the field at ``path`` (the real document nests them inline)."""
    s = body_schema(doc)
    for key in path.split("."):
        s = s["items"] if key == "[]" else s["properties"][key]
    return s


def shown(n: float) -> str:
    """A bound as the form prints it: 64, 0.1, 1,000,000,000."""
    if float(n).is_integer():
        n = int(n)
    return f"{n:,}" if abs(n) >= 1e6 else str(n)


def served(server: LiveServer) -> dict[str, Any]:
    return httpx.get(f"{server.url}/api/openapi.json").json()


def open_form(page: Any, server: LiveServer, bounds: str = "openapi") -> None:
    page.goto(f"{server.url}/submit")
    expect(page.locator("#task-form")).to_have_attribute("data-bounds", bounds)


def posts(state: FakeState) -> list[tuple[str, str, dict[str, str]]]:
    return [r for r in state.requests if r[:2] == ("POST", "/api/tasks")]


def test_inputs_carry_the_bounds_of_the_served_openapi(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    doc = served(server)
    # the fake serves the real gateway's document, built from the core's rules
    assert prop(doc, "env.rows")["maximum"] == MAX_GRID
    assert prop(doc, "env.agents")["maximum"] == MAX_AGENTS
    open_form(page, server)
    for selector, path in INPUTS.items():
        s = prop(doc, path)
        field = page.locator(selector)
        assert float(field.get_attribute("min")) == s["minimum"], selector
        assert float(field.get_attribute("max")) == s["maximum"], selector
        step = field.get_attribute("step")
        assert step == ("1" if s["type"] == "integer" else "any") or path == "observation.window"
    assert prop(doc, "observation.window")["not"] == {"multipleOf": 2}
    expect(page.locator("#f-observation-window")).to_have_attribute("step", "2")  # odd from 3
    for selector, path in (
        ("#f-env-moves", "env.moves"),
        ("#f-observation-kind", "observation.kind"),
    ):
        values = page.locator(f"{selector} option").evaluate_all("os => os.map(o => o.value)")
        assert values == [str(v) for v in prop(doc, path)["enum"]]
    workers = prop(doc, "num_workers")
    expect(page.locator('[data-field="num_workers"] .help')).to_have_text(
        f"{shown(workers['minimum'])} to {shown(workers['maximum'])}, each trains independently"
    )


def test_a_changed_document_changes_the_form(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    """Bounds moved in the served document, in the shapes pydantic emits: a $ref wrapped in
    allOf, a nullable anyOf. The form follows them, so it cannot be keeping its own copy."""
    doc = state.openapi
    schemas = doc["components"]["schemas"]
    props = body_schema(doc)["properties"]
    schemas["Crew"] = {**props["num_workers"], "maximum": 5}
    props["num_workers"] = {"allOf": [{"$ref": "#/components/schemas/Crew"}], "default": 1}
    props["env"]["properties"]["rows"] = {
        "anyOf": [{"type": "integer", "minimum": 4, "maximum": 20}, {"type": "null"}]
    }
    props["env"]["properties"]["moves"]["enum"] = [4]
    props["observation"]["properties"]["window"]["maximum"] = 7
    props["budget"]["properties"]["steps"]["minimum"] = 5000
    for variant in props["env"]["properties"]["intensity"]["anyOf"]:  # a number or {kind, values}
        value = variant["properties"]["values"]["items"] if "properties" in variant else variant
        value["maximum"] = 2e9

    open_form(page, server)
    expect(page.locator("#f-num_workers")).to_have_attribute("max", "5")
    expect(page.locator("#f-env-rows")).to_have_attribute("min", "4")
    expect(page.locator("#f-env-rows")).to_have_attribute("max", "20")
    expect(page.locator("#f-env-cols")).to_have_attribute("max", str(MAX_GRID))  # untouched
    expect(page.locator("#f-observation-window")).to_have_attribute("max", "7")
    expect(page.locator("#f-budget-steps")).to_have_attribute("min", "5000")
    assert page.locator("#f-env-moves option").evaluate_all("os => os.map(o => o.value)") == ["4"]
    expect(page.locator('[data-field="num_workers"] .help')).to_contain_text("1 to 5")

    sign_in_as_alice(page)
    page.fill("#f-num_workers", "6")
    page.fill("#f-env-rows", "21")
    page.fill("#f-observation-window", "9")
    page.fill("#f-budget-steps", "4999")
    page.fill("#f-env-intensity", "3e9")
    page.click("#submit-task")
    expect(page.locator("#err-num_workers")).to_have_text("must be at most 5")
    expect(page.locator("#err-env-rows")).to_have_text("must be at most 20")
    expect(page.locator("#err-observation-window")).to_have_text("must be at most 7")
    expect(page.locator("#err-budget-steps")).to_have_text("must be at least 5000")
    expect(page.locator("#err-env-intensity")).to_have_text(
        "3000000000: must be at most 2,000,000,000"
    )
    assert posts(state) == []

    # inside the moved bounds the same form submits
    page.fill("#f-num_workers", "5")
    page.fill("#f-env-rows", "20")
    page.fill("#f-observation-window", "7")
    page.fill("#f-budget-steps", "5000")
    page.fill("#f-env-intensity", "2e9")
    page.click("#submit-task")
    expect(page.locator("#submit-result")).to_contain_text("created")
    sent = state.posted_tasks[0]
    assert (sent["num_workers"], sent["env"]["rows"], sent["observation"]["window"]) == (5, 20, 7)


#: field -> (path, bound, step past it): each value typed lies just outside its bound
BEYOND = {
    "env-rows": ("env.rows", "maximum", 1),
    "env-agents": ("env.agents", "minimum", -1),
    "env-walls_max": ("env.walls.[]", "maximum", 1),
    "observation-window": ("observation.window", "maximum", 2),  # odd, so the bound is the error
    "budget-steps": ("budget.steps", "maximum", 1),
    "budget-minutes": ("budget.minutes", "minimum", -0.05),
    "seed": ("seed", "maximum", 1),
    "domain": ("domain", "maximum", 1),
    "min_reputation": ("min_reputation", "maximum", 0.5),
    "min_ram_gb": ("min_ram_gb", "maximum", 1),
    "deadline_s": ("deadline_s", "minimum", -1),
}
SAYS = {"maximum": "must be at most", "minimum": "must be at least"}


def test_a_value_past_a_bound_is_refused_on_its_field_before_sending(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    doc = served(server)
    open_form(page, server)
    sign_in_as_alice(page)
    page.fill("#f-env-walls_min", "0")
    for field, (path, bound, step) in BEYOND.items():
        v = prop(doc, path)[bound] + step
        page.fill(f"#f-{field}", str(int(v)) if float(v).is_integer() else str(v))
    intensity = next(v for v in prop(doc, "env.intensity")["anyOf"] if v.get("type") == "number")
    page.fill("#f-env-intensity", f"{intensity['maximum'] * 10:g}")
    # one wei above the gateway's ceiling (a power of ten, read exactly from its JSON number)
    ceiling = int(Decimal(repr(prop(doc, "payment_wei")["maximum"]))) + 1
    page.fill("#f-payment_eth", f"{ceiling // 10**18}.{ceiling % 10**18:018d}")
    page.click("#submit-task")
    for field, (path, bound, _) in BEYOND.items():
        message = f"{SAYS[bound]} {shown(prop(doc, path)[bound])}"
        expect(page.locator(f"#err-{field}")).to_have_text(message)
        expect(page.locator(f"#f-{field}")).to_have_attribute("aria-invalid", "true")
    expect(page.locator("#err-env-intensity")).to_contain_text(
        f"must be at most {shown(intensity['maximum'])}"
    )
    expect(page.locator("#err-payment_eth")).to_contain_text("must be at most")
    expect(page.locator("#form-error")).to_contain_text(f"{len(BEYOND) + 2} field(s) need a fix")
    assert posts(state) == []


def test_values_at_the_bounds_are_accepted_by_form_and_gateway(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    doc = served(server)
    top = {p: prop(doc, p)["maximum"] for p in ("env.rows", "num_workers", "domain", "min_rating")}
    window = prop(doc, "observation.window")["maximum"]
    open_form(page, server)
    sign_in_as_alice(page)
    page.fill("#f-env-rows", shown(top["env.rows"]))
    page.fill("#f-env-cols", shown(top["env.rows"]))
    page.fill("#f-observation-window", shown(window))
    page.fill("#f-num_workers", shown(top["num_workers"]))
    page.fill("#f-domain", shown(top["domain"]))
    page.fill("#f-min_rating", shown(top["min_rating"]))
    page.fill("#f-budget-steps", "")  # minutes alone is a budget
    page.click("#submit-task")
    expect(page.locator("#submit-result")).to_contain_text("created")
    sent = state.posted_tasks[0]
    assert sent["env"]["rows"] == sent["env"]["cols"] == top["env.rows"]
    assert sent["observation"] == {"kind": "odmtl", "window": window}
    assert (sent["num_workers"], sent["domain"]) == (top["num_workers"], top["domain"])
    assert sent["budget"] == {"minutes": 10}


def test_without_the_document_the_gateways_422_lands_on_the_field(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    state.openapi = None
    open_form(page, server, bounds="none")
    expect(page.locator("#bounds-note")).to_be_visible()
    assert page.locator("#f-num_workers").get_attribute("max") is None
    sign_in_as_alice(page)
    page.fill("#f-num_workers", "17")
    page.click("#submit-task")
    expect(page.locator("#err-num_workers")).to_contain_text("less than or equal to 16")
    expect(page.locator("#f-num_workers")).to_have_attribute("aria-invalid", "true")
    page.fill("#f-num_workers", "1")
    page.fill("#f-env-rows", "65")  # refused by the core's parser (TrainingSpec.from_dict)
    page.click("#submit-task")
    expect(page.locator("#err-env-rows")).to_have_text("must be in [2, 64], got 65")
    expect(page.locator("#err-num_workers")).to_have_text("")
    assert len(posts(state)) == 2 and state.posted_tasks == []
    page.fill("#f-env-rows", "10")
    page.click("#submit-task")
    expect(page.locator("#submit-result")).to_contain_text("created")
    assert len(state.posted_tasks) == 1
