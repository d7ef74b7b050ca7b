"""A stand-in gateway for the UI tests: the documented /api shapes (docs/platform.md) over an
in-memory state the tests read and change, plus the real ``mount_frontend``.

It lets the UI be tested while the real routes are written, and records what the browser sent
(query strings, bodies, bearer tokens) so a test can assert on the requests, not only the DOM.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Annotated, Any

from fastapi import FastAPI, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import ValidationError

from backend.api.errors import RuleError, install_error_handlers
from backend.api.frontend import mount_frontend
from backend.schemas.tasks import TaskCreate

ALICE = "0x7E5F4552091A69125d5DfCb7b8C2659029395Bdf"
BOB = "0x2B5AD5c4795c026514f8317c7a215E218DcCD6cF"
W1 = "0x6813Eb9362372EEF6200f3b1dbC3f819671cBA69"
W2 = "0x1efF47bc3a10a45D4B230B5d10E37751FE6AA718"
W3 = "0xe1AB8145F7E55DC933d51a18c793F901A3A0b276"
W4 = "0xE57bFE9F44b819898F47BF37E5AF72a0783e1141"
CID_A = "bafkreihdwdcefgh4dqkjv67uzcmw7ojee6xedzdetojuzjevtenxquvyku"
CID_B = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
CID_C = "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yeq"
CID_D = "bafkreifjjcie6lypi6ny7amxnfftagclbuxndqonfipmb64f2km2devei4"
CID_SPEC = "bafkreiem4twkqzsq2aj4shbycd4yvoj2cx72vezicletlhi7dijjciqpui"
XSS = '<img src=x onerror="window.__xss=1">'


def env(agents: int, rows: int = 10, cols: int = 10, walls: tuple[int, int] = (0, 0)) -> dict:
    return {
        "rows": rows,
        "cols": cols,
        "area_m": [1000.0, 1000.0],
        "agents": agents,
        "intensity": {"kind": "fixed", "values": [1e9]},
        "moves": 4,
        "walls": list(walls),
        "wall_length": None,
        "reward": "shaped",
        "sparse_bonus": 50.0,
        "max_steps": 100,
        "idle_limit": 3,
        "detector_area_cm2": 200.0,
        "dwell_min": 1.0,
        "wall_mu_per_cm": 0.178,
        "wall_thickness_cm": 10.0,
    }


def curve(n: int, *, eval_every: int = 5) -> list[dict]:
    """A plausible learning curve: success rises, search time and cost fall."""
    points = []
    for i in range(n):
        step = (i + 1) * 2048
        p = {
            "update": i + 1,
            "global_step": step,
            "success": round(min(1.0, 0.1 + 0.045 * i), 3),
            "episode_length": round(80 - 2.5 * i, 2),
            "episode_cost": round(120 - 3.1 * i, 2),
        }
        if (i + 1) % eval_every == 0:
            p["eval_success"] = round(min(1.0, 0.15 + 0.045 * i), 3)
        points.append(p)
    return points


def card(env_spec: dict, kind: str, points: list[dict]) -> dict:
    return {
        "format": "drlaas-model/1",
        "created": "2025-05-04T10:11:12+00:00",
        "model": kind.upper(),
        "env": env_spec,
        "observation": {
            "kind": kind,
            "window": 3,
            "walls": None,
            "actor_shape": [6, 3, 3],
            "critic_shape": [6, 10, 10],
        },
        "architecture": {
            "description": "Table 3.1 CNN actor + critic",
            "actor_parameters": 40_805,
            "critic_parameters": 52_101,
            "total_parameters": 92_906,
            "tensors": {},
        },
        "action_space": {
            "per_agent_actions": 5,
            "moves": 4,
            "agents": env_spec["agents"],
            "joint": False,
            "policy_actions": 5,
            "execution": "shared actor applied to each agent's observation (CLDE)",
        },
        "training": {
            "ppo": {"learning_rate": 0.00025},
            "env_steps": points[-1]["global_step"],
            "updates": len(points),
            "wall_time_s": 812.4,
        },
        "metrics": {k: v for k, v in points[-1].items()},
        "code": {"version": "0.1.0"},
    }


def env_vector(e: dict) -> list[int]:
    """The on-chain env attributes (backend.services.specs.env_attributes order)."""
    return [e["rows"], e["cols"], e["agents"], e["moves"], e["walls"][0], e["walls"][1]]


def initial_models() -> list[dict]:
    """ModelDetailPublic rows (backend/schemas/models.py); the list view drops the detail keys."""
    specs = [
        (1, CID_A, ALICE, 3, env(3), "odmtl", 0.842, 0.9, 7, "Three agents, open 10x10 field", 20),
        (2, CID_B, BOB, 2, env(2, walls=(1, 3)), "dmtl", 0.61, 0.78, 2, "Two agents, walls", 12),
        (3, CID_C, W1, 5, env(4, 12, 12), "cmtl", 0.24, 0.4, 0, XSS + " four agents", 8),
        (4, CID_D, W2, 3, env(3, walls=(2, 2)), "odmtl", 0.08, 0.2, 1, "Three agents, 2 walls", 6),
    ]
    models = []
    for mid, cid, owner, domain, e, kind, rep, rating, allocs, desc, n in specs:
        pts = curve(n)
        c = card(e, kind, pts)
        c["metrics"]["curve"] = pts  # a card may carry its whole curve; metrics = card.metrics
        models.append(
            {
                "id": mid,
                "cid": cid,
                "owner": owner,
                "domain": domain,
                "env": env_vector(e),
                "agents": e["agents"],
                "walls_min": e["walls"][0],
                "walls_max": e["walls"][1],
                "reputation": rep,
                "allocations": allocs,
                "rating": rating,
                "description": desc,
                "card": c,
                "metrics": c["metrics"],
                "owner_reputation": round(rep * 0.9, 3),
                "owner_rating": rating,
            }
        )
    return models


LIST_KEYS = (
    "id",
    "cid",
    "owner",
    "domain",
    "env",
    "agents",
    "walls_min",
    "walls_max",
    "reputation",
    "allocations",
    "rating",
)


def worker(
    address: str,
    status: str,
    rep: float,
    rating: float,
    cpu: int,
    ram: int,
    gpu: int,
    domains: list[int],
    counters: tuple[int, int, int],
    wid: int,
) -> dict:
    """WorkerPublic (backend/schemas/workers.py)."""
    return {
        "address": address,
        "worker_id": wid,
        "status": status,
        "domains": domains,
        "cpu_cores": cpu,
        "ram_gb": ram,
        "gpu_series": gpu,
        "reputation": rep,
        "rating": rating,
        "sharing_reputation": 0.5,
        "sharing_rating": 0.5,
        "counters": {
            "assigned": counters[0],
            "accepted": counters[1],
            "completed": counters[2],
            "rating_sum": 4 * counters[2],
            "rating_count": counters[2],
        },
    }


def initial_workers() -> list[dict]:
    # Deliberately not in reputation order: the UI ranks them itself.
    return [
        worker(W1, "active", 0.55, 0.8, 8, 16, 0, [3], (10, 9, 8), 1),
        worker(W2, "active", 0.925, 0.96, 16, 64, 2, [3, 5], (20, 19, 19), 2),
        worker(W3, "idle", 0.12, 0.4, 4, 8, 0, [2], (3, 1, 1), 3),
        worker(W4, "active", 0.7, 0.7, 2, 4, 1, [3], (5, 5, 4), 4),
    ]


def task_spec(agents: int = 3) -> dict:
    """The stored task spec document (backend/api/routes/tasks.py build_spec)."""
    return {
        "format": "drlaas-task/1",
        "env": env(agents),
        "observation": {"kind": "odmtl", "window": 3},
        "budget": {"steps": 20000, "minutes": 10},
        "seed": 0,
        "domain": 3,
    }


def event(name: str, block: int, args: dict) -> dict:
    """EventPublic (backend/schemas/common.py)."""
    return {
        "block_number": block,
        "log_index": 0,
        "tx_hash": "0x" + f"{block:02x}" * 32,
        "contract": "TasksManager",
        "name": name,
        "args": args,
        "block_time": 1_746_352_800 + 3 * block,
    }


def task(
    tid: int, status: str, requester: str, workers: int, reward: int, agents: int = 3, **detail: Any
) -> dict:
    """TaskDetailPublic (backend/schemas/tasks.py)."""
    return {
        "id": tid,
        "requester": requester,
        "domain": 3,
        "status": status,
        "num_workers": workers,
        "reward_wei": str(reward),
        "deadline": 1_746_356_400,
        "min_reputation": 0.0,
        "min_rating": 0.0,
        "min_cpu_cores": 1,
        "min_ram_gb": 1,
        "description": CID_SPEC,
        "offered": len(detail.get("offers", [])),
        "spec": task_spec(agents),
        "timeline": [],
        "offers": [],
        "outcomes": [],
        "progress": [],
        **detail,
    }


TASK_LIST_KEYS = (
    "id",
    "requester",
    "domain",
    "status",
    "num_workers",
    "reward_wei",
    "deadline",
    "min_reputation",
    "min_rating",
    "min_cpu_cores",
    "min_ram_gb",
    "description",
    "offered",
)


def initial_tasks() -> list[dict]:
    t1 = task(
        1,
        "open",
        ALICE,
        2,
        10**16,
        timeline=[
            event("TaskAdded", 12, {"taskId": 1, "requester": ALICE, "numWorkers": 2}),
            event("TaskOffered", 13, {"taskId": 1, "worker": W2, "qos": 910000}),
            event("OfferAccepted", 15, {"taskId": 1, "worker": W2}),
        ],
        offers=[
            {"worker": W2, "state": "accepted", "qos": 0.91, "expiry": 1_746_353_100},
            {"worker": W4, "state": "offered", "qos": 0.62, "expiry": 1_746_353_100},
        ],
        progress=[
            {
                "worker": W2,
                "step": s,
                "success": round(0.1 * k, 2),
                "time": 80 - 5 * k,
                "cost": 100 - 6 * k,
                "extra": None,
            }
            for k, s in enumerate((2048, 4096, 6144), start=1)
        ],
    )
    t2 = task(2, "open", BOB, 1, 5 * 10**15, agents=2)
    t3 = task(
        3,
        "completed",
        ALICE,
        1,
        10**16,
        outcomes=[{"worker": W1, "cid": CID_A, "review": 5, "accepted": True}],
    )
    return [t1, t2, t3]


@dataclass
class FakeState:
    models: list[dict] = field(default_factory=initial_models)
    workers: list[dict] = field(default_factory=initial_workers)
    tasks: list[dict] = field(default_factory=initial_tasks)
    demo_users: bool = True
    requests: list[tuple[str, str, dict[str, str]]] = field(default_factory=list)
    posted_tasks: list[dict[str, Any]] = field(default_factory=list)
    posted_raw: list[str] = field(default_factory=list)
    auth_headers: list[str | None] = field(default_factory=list)

    def reset(self) -> None:
        self.__init__()  # type: ignore[misc]

    def task(self, tid: int) -> dict:
        return next(t for t in self.tasks if t["id"] == tid)

    def queries(self, path: str) -> list[dict[str, str]]:
        return [q for m, p, q in self.requests if m == "GET" and p == path]


TOKENS = {"demo-token-alice": ALICE, "demo-token-bob": BOB}


MAX_AGENTS = 8  # a rule of this fake the UI does not know: tests how a 422 is mapped


def make_fake_app(state: FakeState) -> FastAPI:
    app = FastAPI(openapi_url=None, docs_url=None, redoc_url=None)
    install_error_handlers(app)

    @app.middleware("http")
    async def record(request: Request, call_next: Any) -> Response:
        if request.url.path.startswith("/api/"):
            state.requests.append((request.method, request.url.path, dict(request.query_params)))
        return await call_next(request)

    def caller(request: Request) -> str:
        auth = request.headers.get("authorization", "")
        address = TOKENS.get(auth.removeprefix("Bearer ").strip())
        if not address:
            raise RuleError(401, "unauthorized", "sign in first: no valid bearer token")
        return address

    @app.get("/api/health")
    def health() -> dict:
        return {"status": "ok"}

    @app.get("/api/auth/demo-users")
    def demo_users() -> dict:
        if not state.demo_users:
            raise RuleError(404, "not_found", "no demo users on this gateway")
        users = [{"name": "alice", "address": ALICE}, {"name": "bob", "address": BOB}]
        return {"data": users, "count": len(users)}

    @app.post("/api/auth/demo-token")
    async def demo_token(request: Request) -> dict:
        body = await request.json()
        name = body.get("name")
        if name not in ("alice", "bob"):
            raise RuleError(404, "not_found", f"no demo user {name!r}")
        return {
            "access_token": f"demo-token-{name}",
            "token_type": "bearer",
            "address": TOKENS[f"demo-token-{name}"],
            "expires_at": "2099-01-01T00:00:00Z",
        }

    @app.get("/api/auth/me")
    def me(request: Request) -> dict:
        return {"address": caller(request)}

    @app.get("/api/models")
    def models(
        domain: int | None = None,
        agents: int | None = None,
        walls: int | None = None,
        min_reputation: Annotated[float | None, Query(ge=0, le=1)] = None,
        q: str = "",
    ) -> dict:
        out = [
            {k: m[k] for k in LIST_KEYS}
            for m in state.models
            if (domain is None or m["domain"] == domain)
            and (agents is None or m["agents"] == agents)
            and (walls is None or m["walls_min"] <= walls <= m["walls_max"])
            and (min_reputation is None or m["reputation"] >= min_reputation)
            and (not q or q.lower() in (m["description"] + m["cid"]).lower())
        ]
        return {"data": out, "count": len(out)}

    @app.get("/api/models/{mid}")
    def model(mid: int) -> dict:
        for m in state.models:
            if m["id"] == mid:
                return m
        raise RuleError(404, "model_not_found", f"no model {mid} (or not indexed yet)")

    @app.get("/api/models/{mid}/download")
    def download(mid: int, file: str) -> Response:
        m = model(mid)
        if file == "model.json":
            return Response(json.dumps(m["card"]), media_type="application/json")
        return Response(b"\x00" * 16, media_type="application/octet-stream")

    @app.get("/api/workers")
    def workers(
        sort: str = "reputation", domain: int | None = None, status: str | None = None
    ) -> dict:
        out = [
            w
            for w in state.workers
            if (status is None or w["status"] == status)
            and (domain is None or domain in w["domains"])
        ]
        return {"data": out, "count": len(out)}  # unsorted on purpose

    @app.get("/api/tasks")
    def tasks(status: str | None = None, requester: str | None = None) -> dict:
        out = [
            {k: t[k] for k in TASK_LIST_KEYS}
            for t in sorted(state.tasks, key=lambda t: -t["id"])  # newest first, like the gateway
            if (status is None or t["status"] == status)
            and (requester is None or t["requester"].lower() == requester.lower())
        ]
        return {"data": out, "count": len(out)}

    @app.get("/api/tasks/{tid}")
    def get_task(tid: int) -> dict:
        try:
            return state.task(tid)
        except StopIteration:
            raise RuleError(404, "task_not_found", f"no task {tid}") from None

    @app.post("/api/tasks", status_code=201)
    async def create_task(request: Request) -> JSONResponse:
        raw = (await request.body()).decode()
        state.auth_headers.append(request.headers.get("authorization"))
        requester = caller(request)
        state.posted_raw.append(raw)
        body = json.loads(raw)
        try:
            created = TaskCreate.model_validate(body)  # the real request schema
        except ValidationError as exc:  # 422 {"detail": [{loc: ["body", ...]}]} like a route
            raise RequestValidationError(
                [{**e, "loc": ("body", *e["loc"])} for e in exc.errors()]
            ) from None
        if body["env"].get("agents", 0) > MAX_AGENTS:
            raise RequestValidationError(
                [
                    {
                        "loc": ("body", "env", "agents"),
                        "msg": f"at most {MAX_AGENTS} agents here",
                        "type": "value_error",
                    }
                ]
            )
        state.posted_tasks.append(body)
        tid = max(t["id"] for t in state.tasks) + 1
        spec = {
            "format": "drlaas-task/1",
            "env": body["env"],
            "observation": created.observation.model_dump(),
            "budget": created.budget.model_dump(),
            "seed": created.seed,
            "domain": created.domain,
        }
        state.tasks.append(
            task(tid, "open", requester, created.num_workers, created.payment_wei, spec=spec)
        )
        offered = [W2, W4][: created.num_workers]
        return JSONResponse(
            {"task_id": tid, "spec_cid": CID_SPEC, "offered": offered, "tx_hashes": []},
            status_code=201,
        )

    mount_frontend(app)
    return app
