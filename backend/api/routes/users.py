"""Register the caller on the UMC: as a requester, or as a worker with its capabilities.

Both act only as the signed-in address (docs/platform.md, "Signing"): the gateway signs with
the caller's demo key in development, else answers 409 ``sign_locally`` with the transaction.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, status

from backend.api.deps import ChainDep, CurrentUser, IndexerDep
from backend.api.errors import RuleError, rule_responses
from backend.api.schemas import Address
from backend.api.writes import catch_up
from backend.chain.platform import WorkerStatus, domain_mask
from backend.schemas.users import RegistrationPublic, WorkerCreate

router = APIRouter(prefix="/users", tags=["users"])


@router.post(
    "/requesters",
    status_code=status.HTTP_201_CREATED,
    response_model=RegistrationPublic,
    responses=rule_responses(401, 409, 503),
)
def register_requester(
    user: CurrentUser, chain: ChainDep, indexer: IndexerDep
) -> RegistrationPublic:
    """UMC.addRequester for the caller (409 ``users_already_registered`` the second time). On
    a consortium chain the new requester is ``pending`` until an admin approves it (``POST
    /users/requesters/{address}/approval``): a worker cannot open second identities at will
    to post tasks only it can take (docs/chain.md)."""
    rc = chain.send(user.address, chain.platform.umc, "addRequester")
    catch_up(indexer)
    return RegistrationPublic(
        address=user.address,
        role="requester",
        tx_hash=rc.tx_hash,
        created=True,
        status=_requester_status(chain, user.address),
    )


@router.post(
    "/requesters/{address}/approval",
    response_model=RegistrationPublic,
    responses=rule_responses(401, 403, 409, 503),
)
def approve_requester(
    address: Annotated[Address, Path()], user: CurrentUser, chain: ChainDep, indexer: IndexerDep
) -> RegistrationPublic:
    """UMC.approveRequester by a consortium admin: the pending requester may post tasks (403
    ``users_not_admin`` for anyone else, 409 ``users_requester_not_pending`` if it is not
    pending)."""
    return _act_on(chain, indexer, user.address, "approveRequester", address, "requester")


@router.delete(
    "/requesters/{address}",
    response_model=RegistrationPublic,
    responses=rule_responses(401, 403, 409, 503),
)
def remove_requester(
    address: Annotated[Address, Path()], user: CurrentUser, chain: ChainDep, indexer: IndexerDep
) -> RegistrationPublic:
    """UMC.removeRequester by the requester itself or an admin: no new task or model request
    from it; its tasks already posted run to their end (403 ``users_not_self_or_admin`` for
    anyone else, 409 ``users_requester_not_registered`` if it is not pending or active)."""
    return _act_on(chain, indexer, user.address, "removeRequester", address, "requester")


@router.post(
    "/workers",
    status_code=status.HTTP_201_CREATED,
    response_model=RegistrationPublic,
    responses=rule_responses(401, 403, 409, 503),
)
def register_worker(
    body: WorkerCreate, user: CurrentUser, chain: ChainDep, indexer: IndexerDep
) -> RegistrationPublic:
    """UMC.addWorker, or UMC.updateCapabilities when the caller is already a worker (its
    domains are fixed at registration: 409 ``worker_domains_fixed`` if they differ). At most
    four domains. On a consortium chain the new worker is ``pending`` until an admin approves
    it (``POST /users/workers/{address}/approval``); a removed worker gets 403
    ``users_not_approved``."""
    umc = chain.platform.umc
    if chain.call(umc, "workerId", user.address) == 0:
        rc = chain.send(
            user.address,
            umc,
            "addWorker",
            domain_mask(body.domains),
            body.cpu_cores,
            body.ram_gb,
            body.gpu_series,
        )
        created = True
    else:
        # The UMC updates a removed worker's capabilities (it only checks registration): the
        # gateway refuses, as a removed worker takes no part in the platform any more.
        if _status(chain, user.address) == WorkerStatus.REMOVED.name.lower():
            raise RuleError(
                403,
                "users_not_approved",
                f"worker {user.address} was removed: it cannot update its capabilities",
            )
        if _registered_domains(chain, user.address) != domain_mask(body.domains):
            raise RuleError(
                409,
                "worker_domains_fixed",
                "a worker's domains are fixed at registration; send the registered domains to "
                "update capabilities",
            )
        rc = chain.send(
            user.address, umc, "updateCapabilities", body.cpu_cores, body.ram_gb, body.gpu_series
        )
        created = False
    catch_up(indexer)
    return RegistrationPublic(
        address=user.address,
        role="worker",
        tx_hash=rc.tx_hash,
        created=created,
        status=_status(chain, user.address),
    )


@router.post(
    "/workers/{address}/approval",
    response_model=RegistrationPublic,
    responses=rule_responses(401, 403, 409, 503),
)
def approve_worker(
    address: Annotated[Address, Path()], user: CurrentUser, chain: ChainDep, indexer: IndexerDep
) -> RegistrationPublic:
    """UMC.approveWorker by a consortium admin: the pending worker becomes a candidate (403
    ``users_not_admin`` for anyone else, 409 ``users_not_pending`` if it is not pending)."""
    return _act_on(chain, indexer, user.address, "approveWorker", address, "worker")


@router.delete(
    "/workers/{address}",
    response_model=RegistrationPublic,
    responses=rule_responses(401, 403, 409, 503),
)
def remove_worker(
    address: Annotated[Address, Path()], user: CurrentUser, chain: ChainDep, indexer: IndexerDep
) -> RegistrationPublic:
    """UMC.removeWorker by the worker itself or an admin: it is never offered a task or a
    model again (403 ``users_not_self_or_admin`` for anyone else)."""
    return _act_on(chain, indexer, user.address, "removeWorker", address, "worker")


def _act_on(
    chain: ChainDep, indexer: IndexerDep, sender: str, fn: str, address: str, role: str
) -> RegistrationPublic:
    """One UMC call by ``sender`` about another account (approval, removal) and its answer,
    with the status the chain now holds (an approved worker that had gone idle is Idle
    again, not Active)."""
    rc = chain.send(sender, chain.platform.umc, fn, address)
    catch_up(indexer)
    status = _status(chain, address) if role == "worker" else _requester_status(chain, address)
    return RegistrationPublic(
        address=address, role=role, tx_hash=rc.tx_hash, created=False, status=status
    )


def _requester_status(chain: ChainDep, address: str) -> str:
    status = int(chain.call(chain.platform.umc, "requesterStatus", address))
    return WorkerStatus(status).name.lower()


def _status(chain: ChainDep, address: str) -> str:
    return WorkerStatus(int(chain.call(chain.platform.umc, "getWorker", address)[1])).name.lower()


def _registered_domains(chain: ChainDep, address: str) -> int:
    """Domain bitmask of a registered worker (in its Worker record, or ``domainsOf``)."""
    umc = chain.platform.umc
    names = [
        f["name"]
        for f in umc.contract.get_function_by_name("getWorker")
        .abi["outputs"][0]
        .get("components", [])
    ]
    if "domains" in names:
        return int(chain.call(umc, "getWorker", address)[names.index("domains")])
    return int(chain.call(umc, "domainsOf", address))
