"""Deploy and wire the three platform contracts (UMC, TMC, MMC) and typed handles on them.

:func:`deploy_platform` deploys the Users Manager (UMC), Tasks Manager (TMC) and Models
Manager (MMC), lets the TMC and MMC update worker counters (``UMC.setPlatform``) and returns a
:class:`Platform` whose handles expose the thesis functions with Python names and types.
Fixed-point conventions are those of :mod:`backend.chain.qos` (ONE = 1e6, reviews 0-5).
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from eth_utils import keccak

from . import errors
from .client import Chain, ContractHandle, Receipt

W1_DEFAULT = 100_000  # Eq. 20 weight 0.1 scaled by 1e6 (= qos.W1_DEFAULT)
ACCEPT_WINDOW = 3_600  # seconds a worker has to accept an offer
REVIEW_WINDOW = 7 * 86_400  # seconds a requester has to review after the deadline
MAX_DOMAIN = 47  # UMC keeps a worker's domains as a 48-bit mask
MAX_WORKER_DOMAINS = 4  # UMC.MAX_WORKER_DOMAINS: domains one worker may cover
ALL_GPUS_BUT_NONE = (1 << 256) - 2  # every GPU series code 1-255 accepted; 0 = no GPU


class WorkerStatus(enum.IntEnum):
    NONE = 0
    ACTIVE = 1  # approved, takes offers (in its domains' candidate queues)
    IDLE = 2  # approved, takes no offers
    PENDING = 3  # registered, waiting for an admin's approval
    REMOVED = 4  # removed by itself or an admin


class TaskStatus(enum.IntEnum):
    NONE = 0
    OPEN = 1
    COMPLETED = 2
    CANCELLED = 3
    CLOSED = 4


class OfferState(enum.IntEnum):
    NONE = 0
    OFFERED = 1
    ACCEPTED = 2
    DECLINED = 3
    EXPIRED = 4
    SUBMITTED = 5
    REVIEWED = 6
    FAILED = 7


class Verdict(enum.IntEnum):
    """ITasksOutcomes.Verdict: how an outcome CID's requester judged it."""

    NONE = 0  # no outcome has this CID
    PENDING = 1
    ACCEPTED = 2
    REJECTED = 3


def cid_hash(cid: str) -> bytes:
    """The contracts' key of a CID: keccak256 of its UTF-8 bytes."""
    return keccak(cid.encode())


def cid_commitment(cid: str, worker: str) -> bytes:
    """TMC.cidCommitment: keccak256(cid ++ worker), what ``commitCid`` takes before ``worker``
    reveals ``cid`` (submitOutcome, addModel) in a later block. It hides the CID until the
    reveal and binds it to the worker, so whoever sees a CID first in a reveal cannot hand it
    in ahead of its producer (docs/chain.md, "front-running a CID, by commit-reveal")."""
    return keccak(cid.encode() + bytes.fromhex(worker.removeprefix("0x")))


class Metric(enum.IntEnum):
    MODEL = 0  # Eq. 10-13 (thesis 5.3.1)
    SHARING = 1  # Eq. 22-23 (thesis 7.5.2)


def domain_mask(domains: Iterable[int]) -> int:
    """Bitmask of domain codes (0-47) as the UMC stores them."""
    mask = 0
    for d in domains:
        if not 0 <= d <= MAX_DOMAIN:
            raise ValueError(f"domain codes must be in [0, {MAX_DOMAIN}], got {d}")
        mask |= 1 << d
    return mask


def gpu_mask(series: Iterable[int]) -> int:
    """Bitmask of accepted GPU series codes (0-255) for the TMC constructor."""
    mask = 0
    for s in series:
        if not 0 <= s <= 255:
            raise ValueError(f"GPU series codes must be in [0, 255], got {s}")
        mask |= 1 << s
    return mask


class UsersManager(ContractHandle):
    """UMC (thesis Table 7.2): registration, status and per-domain worker counters."""

    def add_worker(
        self, sender: str, domains: Iterable[int], cpu_cores: int, ram_gb: int, gpu_series: int
    ) -> Receipt:
        return self.transact(
            "addWorker", domain_mask(domains), cpu_cores, ram_gb, gpu_series, sender=sender
        )

    def add_requester(self, sender: str) -> Receipt:
        """Register ``sender`` as a requester: Active, or Pending where approval is required."""
        return self.transact("addRequester", sender=sender)

    def requester_status(self, requester: str) -> WorkerStatus:
        """NONE, ACTIVE, PENDING (waiting for an admin's approval) or REMOVED."""
        return WorkerStatus(self.call("requesterStatus", requester))

    def approve_requester(self, sender: str, requester: str) -> Receipt:
        """An admin approves a Pending requester (it may post tasks and request models)."""
        return self.transact("approveRequester", requester, sender=sender)

    def remove_requester(self, sender: str, requester: str) -> Receipt:
        """The requester itself or an admin removes ``requester`` for good."""
        return self.transact("removeRequester", requester, sender=sender)

    def update_status(self, sender: str, status: WorkerStatus) -> Receipt:
        return self.transact("updateStatus", int(status), sender=sender)

    def status(self, worker: str) -> WorkerStatus:
        return WorkerStatus(self.call("getWorker", worker)[1])

    def approve_worker(self, sender: str, worker: str) -> Receipt:
        """An admin approves a Pending worker (it becomes Active, a candidate)."""
        return self.transact("approveWorker", worker, sender=sender)

    def remove_worker(self, sender: str, worker: str) -> Receipt:
        """The worker itself or an admin removes ``worker`` for good."""
        return self.transact("removeWorker", worker, sender=sender)

    def set_approval_required(self, sender: str, required: bool) -> Receipt:
        return self.transact("setApprovalRequired", required, sender=sender)

    def set_pool_size(self, sender: str, size: int) -> Receipt:
        return self.transact("setPoolSize", size, sender=sender)

    def pool(self, domain: int) -> list[str]:
        """The domain's candidate pool (first ``poolSize`` of its Active queue), in order."""
        return list(self.call("pool", domain))

    def queue(self, domain: int) -> list[str]:
        """The domain's whole Active queue (pool first, then the waiting workers)."""
        return list(self.call("queue", domain))

    def counters(self, worker: str, domain: int, task_type: int) -> dict[str, int]:
        c = self.call("counters", worker, domain, task_type)
        names = ("assigned", "accepted", "completed", "rating_sum", "rating_count")
        return dict(zip(names, c, strict=True))

    #: Workers per getWorkers page (the view is paged so its gas is bounded by the page).
    WORKERS_PAGE = 20

    def get_workers(self, domain: int) -> list[dict[str, Any]]:
        """All workers of `domain` in registration order, read page by page."""
        names = ("address", "status", "gpu_series", "cpu_cores", "ram_gb", "domains")
        out: list[dict[str, Any]] = []
        while True:
            page = self.call("getWorkers", domain, len(out), self.WORKERS_PAGE)
            out.extend(dict(zip(names, w, strict=True)) for w in page)
            if len(page) < self.WORKERS_PAGE:
                return out


class TasksManager(ContractHandle):
    """TMC (thesis Table 7.3): training tasks, recruitment, offers, outcomes, payments."""

    def add_task(
        self,
        sender: str,
        *,
        domain: int,
        num_workers: int,
        reward: int,
        duration: int,
        min_reputation: int = 0,
        min_rating: int = 0,
        min_cpu_cores: int = 0,
        min_ram_gb: int = 0,
        description: str = "",
    ) -> tuple[int, Receipt]:
        """addTask with ``reward`` per worker escrowed; returns (task id, receipt)."""
        params = (
            domain,
            num_workers,
            min_reputation,
            min_rating,
            min_cpu_cores,
            min_ram_gb,
            duration,
            description,
        )
        rc = self.transact("addTask", params, sender=sender, value=reward * num_workers)
        return rc.one("TaskAdded").args["taskId"], rc

    def allocate(self, sender: str, task_id: int) -> tuple[list[str], Receipt]:
        """allocateTask; returns (offered workers best first, receipt)."""
        rc = self.transact("allocateTask", task_id, sender=sender)
        return [e.args["worker"] for e in rc.named("TaskOffered")], rc

    def offer(self, task_id: int, worker: str) -> dict[str, int]:
        state, expiry, worker_id, paid = self.call("getOffer", task_id, worker)
        return {"state": OfferState(state), "expiry": expiry, "worker_id": worker_id, "paid": paid}

    def commit_cid(self, sender: str, cid: str) -> Receipt:
        """commitCid of ``cid`` for ``sender``; returns once a later block exists, where the
        CID may be revealed. Idempotent: a repeated commitment keeps its first block."""
        rc = self.transact("commitCid", cid_commitment(cid, sender), sender=sender)
        self.chain.await_block_after(rc.block_number)
        return rc

    def submit_outcome(self, sender: str, task_id: int, cid: str) -> Receipt:
        """Commit ``cid``, then submitOutcome with it (the two transactions of commit-reveal);
        the receipt of the reveal."""
        self.commit_cid(sender, cid)
        return self.transact("submitOutcome", task_id, cid, sender=sender)

    def outcome_of(self, cid: str) -> tuple[str, int, Verdict]:
        """(worker, task id, verdict) of the outcome ``cid``; (0x0.., 0, NONE) if none."""
        worker, task_id, verdict = self.call("outcomeOf", cid_hash(cid))
        return worker, task_id, Verdict(verdict)

    def min_reward(self, duration: int) -> int:
        """Least reward per worker (wei) addTask accepts for ``duration`` seconds."""
        return int(self.call("minRewardForDuration", duration))

    def set_min_reward_per_hour(self, sender: str, wei_per_hour: int) -> Receipt:
        return self.transact("setMinRewardPerHour", wei_per_hour, sender=sender)

    def set_task_limits(self, sender: str, min_work_time: int, max_duration: int) -> Receipt:
        """setTaskLimits: least work time after the acceptance window, longest duration (s)."""
        return self.transact("setTaskLimits", min_work_time, max_duration, sender=sender)

    def duration_bounds(self) -> tuple[int, int]:
        """(shortest, longest) task duration addTask accepts now, in seconds."""
        shortest = int(self.call("acceptWindow")) + int(self.call("minWorkTime"))
        return shortest, int(self.call("maxDuration"))

    def cancel_open_slots(self, sender: str, task_id: int) -> tuple[int, Receipt]:
        """cancelOpenSlots; returns (slots cancelled, receipt)."""
        rc = self.transact("cancelOpenSlots", task_id, sender=sender)
        return rc.one("SlotsCancelled").args["cancelled"], rc

    def task(self, task_id: int) -> dict[str, Any]:
        t, r = self.call("getTask", task_id)
        keys_t = (
            "requester",
            "status",
            "num_workers",
            "live_offers",
            "filled",
            "settled",
            "offer_count",
            "deadline",
        )
        keys_r = (
            "domain",
            "min_reputation",
            "min_rating",
            "min_cpu_cores",
            "min_ram_gb",
            "reward",
            "review_end",
        )
        out = dict(zip(keys_t, t, strict=True)) | dict(zip(keys_r, r, strict=True))
        out["status"] = TaskStatus(out["status"])
        return out


class ModelsManager(ContractHandle):
    """MMC (thesis Tables 5.2, 7.4): shared models, allocation by QoS, reviews."""

    def add_model(
        self, sender: str, cid: str, domain: int, env: Sequence[int], description: str = ""
    ) -> tuple[int, Receipt]:
        """addModel, after committing ``cid`` on the TMC unless it is already an outcome
        (whose record stands for the commitment); returns (model id, receipt)."""
        tmc = _typed(self.chain.register("TasksManager", self.call("tmc")), TasksManager)
        if tmc.outcome_of(cid)[2] == Verdict.NONE:
            # not a worker: addModel says so itself (ModelsNotWorker)
            with contextlib.suppress(errors.get("TasksNotWorker")):
                tmc.commit_cid(sender, cid)
        rc = self.transact("addModel", cid, description, domain, list(env), sender=sender)
        return rc.one("ModelAdded").args["modelId"], rc

    def set_min_model_price(self, sender: str, wei_per_model: int) -> Receipt:
        return self.transact("setMinModelPrice", wei_per_model, sender=sender)

    def set_max_models_per_owner(self, sender: str, limit: int) -> Receipt:
        return self.transact("setMaxModelsPerOwner", limit, sender=sender)

    def model_of_cid(self, cid: str) -> int:
        """Id of the model listing ``cid`` (0 if none)."""
        return int(self.call("modelOfCid", cid_hash(cid)))

    def allocate(
        self,
        sender: str,
        *,
        domain: int,
        num_models: int,
        env: Sequence[int],
        price: int = 1,
        metric: Metric = Metric.SHARING,
        min_reputation: int = 0,
        min_rating: int = 0,
        min_model_reputation: int = 0,
        weights: Sequence[int] = (),
    ) -> tuple[int, list[int], Receipt]:
        """allocateModel paying ``price`` per model (default: the contract's default minimum,
        1 wei); returns (allocation id, model ids best first, receipt)."""
        req = (
            domain,
            num_models,
            int(metric),
            min_reputation,
            min_rating,
            min_model_reputation,
            list(env),
            list(weights),
        )
        rc = self.transact("allocateModel", req, sender=sender, value=price * num_models)
        alloc_id = rc.one("ModelsRequested").args["allocId"]
        return alloc_id, [e.args["modelId"] for e in rc.named("ModelAllocated")], rc


@dataclasses.dataclass
class Platform:
    """Handles on the deployed UMC, TMC and MMC plus the deployment receipts."""

    chain: Chain
    admin: str
    umc: UsersManager
    tmc: TasksManager
    mmc: ModelsManager
    receipts: dict[str, Receipt]
    _identity: str | None = dataclasses.field(default=None, init=False, repr=False)

    @property
    def contracts(self) -> tuple[ContractHandle, ...]:
        return (self.umc, self.tmc, self.mmc)

    @property
    def deployed_at(self) -> int:
        """Block of the first deployment transaction (where an indexer starts); only for a
        platform this process deployed (attached ones have no receipts)."""
        return min(r.block_number for r in self.receipts.values())

    def record(self, deploy_block: int) -> dict[str, Any]:
        """The deployment as a ``DRLAAS_CONTRACTS`` document: what another process attaches with
        (``connect_platform``) and an indexer starts from."""
        return {
            "UsersManager": self.umc.address,
            "TasksManager": self.tmc.address,
            "ModelsManager": self.mmc.address,
            "admin": self.admin,
            "deploy_block": deploy_block,
            "chain_id": self.chain.chain_id,
        }

    @property
    def identity(self) -> str:
        """This deployment on this chain: a hash of the genesis block and the three contract
        addresses. Anything kept per task off chain (a worker's job directory, a queued job) is
        keyed by it, so a task id of another chain (a restarted dev node) never matches."""
        if self._identity is None:
            parts = [self.chain.genesis_hash, *(h.address for h in self.contracts)]
            self._identity = keccak(text="|".join(p.lower() for p in parts)).hex()[:16]
        return self._identity


def _typed(handle: ContractHandle, cls: type[ContractHandle]) -> Any:
    return cls(handle.chain, handle.name, handle.contract)


CONTRACT_NAMES = ("UsersManager", "TasksManager", "ModelsManager")


def connect_platform(chain: Chain, addresses: Mapping[str, Any], admin: str = "") -> Platform:
    """Typed handles on a deployment already on ``chain`` (``addresses`` by contract name). The
    one way the gateway and the worker daemon attach; ``admin`` is who the handles act for by
    default (the deployer for the gateway, the worker itself for a daemon)."""
    handles = {name: chain.register(name, addresses[name]) for name in CONTRACT_NAMES}
    return Platform(
        chain,
        admin,
        _typed(handles["UsersManager"], UsersManager),
        _typed(handles["TasksManager"], TasksManager),
        _typed(handles["ModelsManager"], ModelsManager),
        {},
    )


def deploy_platform(
    chain: Chain,
    admin: str | None = None,
    *,
    w1: int = W1_DEFAULT,
    accept_window: int = ACCEPT_WINDOW,
    review_window: int = REVIEW_WINDOW,
    accepted_gpus: int = ALL_GPUS_BUT_NONE,
    min_reward_per_hour: int = 0,
    min_model_price: int = 0,
    task_limits: tuple[int, int] | None = None,
    worker_approval: bool = True,
    pool_size: int | None = None,
    max_models_per_owner: int | None = None,
) -> Platform:
    """Deploy UMC, TMC and MMC from ``admin`` (default: first account) and wire them.

    Set by the admin right after deployment when given (0 / None = the contract default):
    ``min_reward_per_hour``, the TMC's anti-spam minimum (wei per worker-hour);
    ``min_model_price``, the MMC's least price per model (wei; the contract default is 1);
    ``task_limits``, the TMC's (minWorkTime, maxDuration) in seconds; ``pool_size`` /
    ``max_models_per_owner``, the UMC candidate pool size per domain and the MMC's models per
    owner. ``worker_approval``: new workers wait for an admin's approval (the contract's
    default); a development chain switches it off so that registration makes a worker a
    candidate at once."""
    admin = admin or chain.accounts[0]
    umc, r_umc = chain.deploy("UsersManager", admin, sender=admin)
    tmc, r_tmc = chain.deploy(
        "TasksManager",
        umc.address,
        w1,
        accept_window,
        review_window,
        accepted_gpus,
        sender=admin,
    )
    mmc, r_mmc = chain.deploy("ModelsManager", umc.address, tmc.address, sender=admin)
    umc.transact("setPlatform", tmc.address, True, sender=admin)
    umc.transact("setPlatform", mmc.address, True, sender=admin)
    tmc.transact("setModels", mmc.address, sender=admin)  # listed CIDs are no outcomes
    if min_reward_per_hour:
        tmc.transact("setMinRewardPerHour", min_reward_per_hour, sender=admin)
    if min_model_price:
        mmc.transact("setMinModelPrice", min_model_price, sender=admin)
    if task_limits is not None:
        tmc.transact("setTaskLimits", *task_limits, sender=admin)
    if not worker_approval:
        umc.transact("setApprovalRequired", False, sender=admin)
    if pool_size is not None:
        umc.transact("setPoolSize", pool_size, sender=admin)
    if max_models_per_owner is not None:
        mmc.transact("setMaxModelsPerOwner", max_models_per_owner, sender=admin)
    return Platform(
        chain,
        admin,
        _typed(umc, UsersManager),
        _typed(tmc, TasksManager),
        _typed(mmc, ModelsManager),
        {"UsersManager": r_umc, "TasksManager": r_tmc, "ModelsManager": r_mmc},
    )
