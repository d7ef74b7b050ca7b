// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

import {Math} from "@openzeppelin/contracts/utils/math/Math.sol";

/**
 * @title UsersManager (UMC, thesis Table 7.2)
 * @dev Registers workers and requesters and keeps, per worker, domain and task type, the
 * counters the recruitment QoS needs (Eq. 16-19 and the rating): offers assigned (A),
 * accepted (Ac), completed (E), review sum and review count. Only platform contracts (the
 * TMC and the MMC, set by the admins) update counters. The consortium admins are kept here and
 * the TMC/MMC ask `isAdmin`. Who is an admin and which contracts may write counters change
 * only by a majority of the admins ({setAdmin}, {setPlatform}, {quorum}): no single member
 * can remove the others or let a contract of its own rewrite reputations. A two-mapping role set instead of OpenZeppelin AccessControl:
 * AccessControl (role admins, ERC-165, renounce) added ~1.2 kB of runtime, i.e. ~250k deploy
 * gas, for features this consortium does not use.
 *
 * Domains are codes 0-47 kept as a 48-bit mask inside the worker slot (O(1) membership
 * test); GPU series are codes 0-255 (0 = no GPU); cores and RAM (GB) are uint16.
 *
 * Registration that a stranger cannot flood (issue 8): a new worker is Pending until a
 * consortium admin approves it ({approveWorker}) while {approvalRequired} is on (the default;
 * a development chain may switch it off, then registration approves at once); a worker covers
 * at most {MAX_WORKER_DOMAINS} domains; the worker itself or an admin removes it for good
 * ({removeWorker}). Pending, Idle and Removed workers are never candidates.
 *
 * Requesters too (the sybil-requester finding of docs/chain.md): while {approvalRequired} is
 * on a new requester is Pending until an admin approves it ({approveRequester}), so a worker
 * cannot open a second identity at will to post tasks only it can take and review itself;
 * the consortium knows who is behind each approved address. An admin or the requester itself
 * removes it for good ({removeRequester}); its tasks already posted run to their end. A worker
 * whose capabilities change after approval is Pending again until re-approved
 * ({updateCapabilities}): approval covers what it declared, not what it declares later.
 *
 * Candidate pools (allocation whose gas does not grow with everyone who ever registered):
 * per domain, the approved Active workers form a queue in the order they last became Active
 * (a doubly linked list: joining appends, leaving unlinks, both O(1)); the domain's candidate
 * pool is the first {poolSize} workers of that queue (admin setting, at most
 * {MAX_POOL_SIZE}). {candidates} returns the pool only, so the TMC's and MMC's allocation
 * cost is bounded by the pool size, not by the number of registered workers. A worker behind
 * the pool enters it when a worker ahead goes Idle or is removed; an admin removes (or a
 * worker idles) an unresponsive pool member. backend/chain/qos.py models the same rule
 * (`domain_pool`); docs/chain.md, "Candidate pools".
 *
 * Gas: a worker is one storage slot (address, status, GPU, cores, RAM, domains) and each
 * counter set is one slot (five uint48: 2.8e14 tasks before overflow); domain lists hold
 * uint32 ids, seven per slot with the count in the first, so a candidate scan costs three
 * cold SLOADs per worker (worker, counters, queue link) and addWorker writes at most two new
 * slots of its own (worker, id) plus, per domain, a list word and a queue link when those
 * are new (docs/chain.md, "Gas against Table 7.5").
 */
contract UsersManager {

    uint8 public constant TRAINING = 0;
    uint8 public constant SHARING = 1;

    // updateInfo flags: which counters a platform event increments.
    uint8 public constant ASSIGNED = 1;
    uint8 public constant ACCEPTED = 2;
    uint8 public constant COMPLETED = 4;
    uint8 public constant REVIEWED = 8;

    // kinds of change that need a majority of the admins ({changeProposal})
    uint8 public constant ADMIN_CHANGE = 0;
    uint8 public constant PLATFORM_CHANGE = 1;

    uint256 internal constant REVIEW_MAX = 5;
    uint256 internal constant MEMBER_BIT = 1 << 255;
    uint256 public constant MAX_DOMAIN = 47;
    uint256 internal constant DOMAINS_SHIFT = 208;
    uint256 internal constant WORKER_FIELDS = (1 << DOMAINS_SHIFT) - 1; // all but the domains
    uint256 internal constant ID_SHIFT = 208; // candidate words carry the worker id here
    /// A worker covers at most this many domains (one registration joins at most 4 pools).
    uint256 public constant MAX_WORKER_DOMAINS = 4;
    /// Upper bound of {poolSize}: allocation reads at most this many candidates per call.
    uint256 public constant MAX_POOL_SIZE = 128;
    uint32 public constant DEFAULT_POOL_SIZE = 64;
    uint256 internal constant ID_MASK = (1 << 32) - 1;
    uint256 internal constant LIST_PER_WORD = 7;
    uint256 internal constant LIST_COUNT_SHIFT = 224;

    enum Status {
        None,
        Active, // takes offers ("available" in qos.py); in its domains' queues
        Idle, // approved, takes no offers
        Pending, // registered, waiting for an admin's approval
        Removed // removed by itself or an admin; never a candidate again
    }

    struct Worker {
        address addr;
        Status status;
        uint8 gpuSeries;
        uint16 cpuCores;
        uint16 ramGb;
        uint48 domains; // bit d = domain code d
    }

    struct Counters {
        uint48 assigned;
        uint48 accepted;
        uint48 completed;
        uint48 ratingSum;
        uint48 ratingCount;
    }

    error UsersNotAdmin(address account);
    error UsersNotPlatform(address account);
    error UsersLastAdmin(address account);
    error UsersAlreadyVoted(address admin, bytes32 proposal);
    error UsersAlreadyRegistered(address account);
    error UsersNotWorker(address account);
    error UsersNotWorkerId(uint32 id);
    error UsersBadDomains(uint256 domains);
    error UsersTooManyDomains(uint256 domains, uint256 maximum);
    error UsersNotPending(address account, Status status);
    error UsersNotApproved(address account, Status status);
    error UsersRequesterNotPending(address account, Status status);
    error UsersRequesterNotRegistered(address account, Status status);
    error UsersNotSelfOrAdmin(address account, address worker);
    error UsersBadPoolSize(uint256 size);
    error UsersBadDomain(uint256 domain);
    error UsersBadStatus(uint8 status);
    error UsersBadTaskType(uint8 taskType);
    error UsersBadReview(uint8 review);
    error UsersBadFlags(uint8 flags);
    error UsersCountersInconsistent(address worker, uint256 domain, uint8 taskType);

    event AdminUpdated(address indexed account, bool isAdmin);
    event PlatformUpdated(address indexed account, bool isPlatform);
    event ChangeVoted(
        bytes32 indexed proposal, address indexed admin, uint8 kind, address account, bool on, uint256 votes, uint256 quorum
    );
    event WorkerAdded(
        address indexed worker, uint32 indexed id, uint256 domains, uint16 cpuCores, uint16 ramGb, uint8 gpuSeries
    );
    event RequesterAdded(address indexed requester);
    event RequesterApproved(address indexed requester, address indexed admin);
    event RequesterRemoved(address indexed requester, address indexed by);
    event RequesterStatusUpdated(address indexed requester, Status status);
    event WorkerApproved(address indexed worker, address indexed admin);
    event WorkerRemoved(address indexed worker, address indexed by);
    event ApprovalRequiredUpdated(bool required);
    event PoolSizeUpdated(uint256 size);
    event WorkerStatusUpdated(address indexed worker, Status status);
    event WorkerCapabilitiesUpdated(address indexed worker, uint16 cpuCores, uint16 ramGb, uint8 gpuSeries);
    event WorkerInfoUpdated(
        address indexed worker,
        uint32 indexed domain,
        uint8 indexed taskType,
        uint48 assigned,
        uint48 accepted,
        uint48 completed,
        uint48 ratingSum,
        uint48 ratingCount
    );

    /// Workers List (thesis: address -> Worker); ids start at 1, 0 = not a worker.
    mapping(uint32 => Worker) internal _workers;
    mapping(address => uint32) public workerId;
    /// Domain Workers (thesis: uint -> address[]), as worker ids in registration order,
    /// LIST_PER_WORD per word: entry i at bits 32 * (i % 7) of word i / 7; word 0 also holds
    /// the count at bits LIST_COUNT_SHIFT.. (a domain's first worker writes one new slot).
    mapping(uint256 => mapping(uint256 => uint256)) internal _domainWorkers;
    /// Counters per (worker id, domain, task type): key = id << 16 | domain << 8 | type.
    mapping(uint256 => Counters) internal _counters;
    /// Requesters: Active (posts tasks and requests models), Pending (waits for an admin's
    /// approval) or Removed; None = never registered. Idle is not used for requesters.
    mapping(address => Status) public requesterStatus;

    mapping(address => bool) public isAdmin;
    mapping(address => bool) public isPlatform;
    uint256 public adminCount;

    /// Votes on changes of the admin set and the platform set ({setAdmin}, {setPlatform}):
    /// proposal ({changeProposal}) -> admins that asked for it, and who did. A proposal names
    /// {changeNonce}, which every applied change advances, so votes cast before any change of
    /// either set lapse (the quorum and the voters they counted on may have changed).
    mapping(bytes32 => uint256) public changeVotes;
    mapping(bytes32 => mapping(address => bool)) public hasVoted;
    uint256 public changeNonce;

    /// New workers wait for an admin's approval (Pending) while true. Admin setting.
    bool public approvalRequired;
    /// Candidates per domain: the first `poolSize` workers of the domain's Active queue.
    uint32 public poolSize;
    /// Workers ever registered (ids 1..workerCount). In the slot of the two settings above,
    /// which the constructor writes, so the first registration does not create a slot.
    uint32 public workerCount;
    /// Active queue links per (domain << 32 | id): prev | next << 32 (ids; 0 = none).
    mapping(uint256 => uint256) internal _links;
    /// Active queue ends per domain: head | tail << 32 | length << 64.
    mapping(uint256 => uint256) internal _queues;
    /// Workers Pending again after a change of capabilities made while Idle: their
    /// re-approval restores Idle, not Active (a worker that chose to pause stays paused).
    mapping(uint32 => bool) internal _idleOnApproval;

    modifier onlyAdmin() {
        _checkAdmin();
        _;
    }

    constructor(address admin) {
        isAdmin[admin] = true;
        adminCount = 1;
        emit AdminUpdated(admin, true);
        approvalRequired = true;
        emit ApprovalRequiredUpdated(true);
        poolSize = DEFAULT_POOL_SIZE;
        emit PoolSizeUpdated(DEFAULT_POOL_SIZE);
    }

    // ---------------------------------------------------------------------------- admin

    /**
     * @dev Votes to add or remove a consortium admin; the change happens when a majority of
     * the admins ({quorum}) voted for it, so no single admin can remove the others and hold
     * the registry alone. One admin (a new consortium, a development chain) decides alone; an
     * admin that removes itself needs no votes. No change (already so): no vote.
     * Requirements: caller is an admin that has not voted for this proposal; the last admin
     * cannot be removed. Emits a {ChangeVoted} event for a vote that does not yet reach the
     * quorum, an {AdminUpdated} event for the change.
     */
    function setAdmin(address account, bool on) external onlyAdmin {
        if (isAdmin[account] == on) return;
        if (!on && adminCount == 1) revert UsersLastAdmin(account);
        if (!(account == msg.sender || _voteCarries(ADMIN_CHANGE, account, on))) return;
        isAdmin[account] = on;
        adminCount = on ? adminCount + 1 : adminCount - 1;
        ++changeNonce;
        emit AdminUpdated(account, on);
    }

    /**
     * @dev Votes to allow or forbid a platform contract (TMC, MMC) to call {updateInfo}; as
     * {setAdmin}, the change needs a majority of the admins: a contract allowed here can
     * rewrite every worker's counters, i.e. its reputation.
     * Requirements: caller is an admin that has not voted for this proposal. Emits a
     * {ChangeVoted} event before the quorum, a {PlatformUpdated} event for the change.
     */
    function setPlatform(address account, bool on) external onlyAdmin {
        if (isPlatform[account] == on) return;
        if (!_voteCarries(PLATFORM_CHANGE, account, on)) return;
        isPlatform[account] = on;
        ++changeNonce;
        emit PlatformUpdated(account, on);
    }

    /// @dev Votes a change of the admin or platform set needs: a majority of the admins.
    function quorum() public view returns (uint256) {
        return adminCount / 2 + 1;
    }

    /// @dev The proposal a vote of {setAdmin} (`kind` 0) or {setPlatform} (1) counts for.
    function changeProposal(uint8 kind, address account, bool on) public view returns (bytes32) {
        return keccak256(abi.encode(kind, account, on, changeNonce));
    }

    /**
     * @dev Switches the approval of new workers on or off. Off (a development chain), a new
     * worker is Active at registration. Workers already Pending stay Pending.
     * Requirements: caller is an admin. Emits an {ApprovalRequiredUpdated} event.
     */
    function setApprovalRequired(bool required) external onlyAdmin {
        approvalRequired = required;
        emit ApprovalRequiredUpdated(required);
    }

    /**
     * @dev Sets the candidate pool size per domain (the first `size` workers of each domain's
     * Active queue are candidates). Requirements: caller is an admin; 1 <= size <=
     * MAX_POOL_SIZE. Emits a {PoolSizeUpdated} event.
     */
    function setPoolSize(uint256 size) external onlyAdmin {
        if (size == 0 || size > MAX_POOL_SIZE) revert UsersBadPoolSize(size);
        poolSize = uint32(size);
        emit PoolSizeUpdated(size);
    }

    /**
     * @dev Approves a Pending worker: it becomes Active and joins the tail of each of its
     * domains' queues, or, if it was Idle when its capabilities changed, Idle again (out of
     * the queues until it sets itself Active). Requirements: caller is an admin; `worker` is
     * Pending. Emits {WorkerApproved} and {WorkerStatusUpdated} events.
     */
    function approveWorker(address worker) external onlyAdmin {
        uint32 id = _workerIdOf(worker);
        Worker storage w = _workers[id];
        if (w.status != Status.Pending) revert UsersNotPending(worker, w.status);
        Status next = Status.Active;
        if (_idleOnApproval[id]) {
            delete _idleOnApproval[id];
            next = Status.Idle;
        } else {
            _join(id, w.domains);
        }
        w.status = next;
        emit WorkerApproved(worker, msg.sender);
        emit WorkerStatusUpdated(worker, next);
    }

    /**
     * @dev Removes a worker for good: it leaves its domains' queues and is never offered a
     * task or a model again (offers already made stay valid). Its address cannot register
     * again. Requirements: caller is the worker itself or an admin; `worker` is registered
     * and not yet removed. Emits {WorkerRemoved} and {WorkerStatusUpdated} events.
     */
    function removeWorker(address worker) external {
        if (msg.sender != worker && !isAdmin[msg.sender]) revert UsersNotSelfOrAdmin(msg.sender, worker);
        uint32 id = _workerIdOf(worker);
        Worker storage w = _workers[id];
        Status old = w.status;
        if (old == Status.Removed) revert UsersNotApproved(worker, old);
        if (old == Status.Active) _leave(id, w.domains);
        w.status = Status.Removed;
        emit WorkerRemoved(worker, msg.sender);
        emit WorkerStatusUpdated(worker, Status.Removed);
    }

    // ---------------------------------------------------------------------------- users

    /**
     * @dev Registers msg.sender as a worker covering the domains set in `domains` (bit d =
     * domain code d, thesis Domains uint[]) with the given computational capabilities
     * (Table 7.2). The worker is Pending (no offers) until an admin approves it, or Active
     * at once (joining its domains' queues) when {approvalRequired} is off.
     * Requirements: not yet a worker (a removed address cannot come back); 1 to
     * MAX_WORKER_DOMAINS domains, all codes <= 47.
     * Emits a {WorkerAdded} event, and a {WorkerStatusUpdated} event when Pending.
     */
    function addWorker(uint256 domains, uint16 cpuCores, uint16 ramGb, uint8 gpuSeries) external {
        if (workerId[msg.sender] != 0) revert UsersAlreadyRegistered(msg.sender);
        if (domains == 0 || domains >> (MAX_DOMAIN + 1) != 0) revert UsersBadDomains(domains);
        uint256 count = 0;
        for (uint256 bits = domains; bits != 0; bits &= bits - 1) ++count;
        if (count > MAX_WORKER_DOMAINS) revert UsersTooManyDomains(domains, MAX_WORKER_DOMAINS);
        bool pending = approvalRequired;
        Status status = pending ? Status.Pending : Status.Active;
        uint32 id = ++workerCount;
        _workers[id] = Worker(msg.sender, status, gpuSeries, cpuCores, ramGb, uint48(domains));
        workerId[msg.sender] = id;
        uint256 rest = domains;
        while (rest != 0) {
            uint256 low = rest & (~rest + 1);
            _listWorker(Math.log2(low), id);
            rest ^= low;
        }
        if (!pending) _join(id, domains);
        emit WorkerAdded(msg.sender, id, domains, cpuCores, ramGb, gpuSeries);
        if (pending) emit WorkerStatusUpdated(msg.sender, Status.Pending);
    }

    /**
     * @dev Registers msg.sender as a requester: Active at once when {approvalRequired} is off,
     * else Pending until an admin approves it ({approveRequester}).
     * Requirements: never registered as a requester (a removed address cannot come back).
     * Emits a {RequesterStatusUpdated} event, and a {RequesterAdded} event when Active.
     */
    function addRequester() external {
        Status old = requesterStatus[msg.sender];
        if (old != Status.None) revert UsersAlreadyRegistered(msg.sender);
        Status status = approvalRequired ? Status.Pending : Status.Active;
        requesterStatus[msg.sender] = status;
        emit RequesterStatusUpdated(msg.sender, status);
        if (status == Status.Active) emit RequesterAdded(msg.sender);
    }

    /**
     * @dev Approves a Pending requester: it may post tasks and request models.
     * Requirements: caller is an admin; `requester` is Pending.
     * Emits {RequesterApproved}, {RequesterStatusUpdated} and {RequesterAdded} events.
     */
    function approveRequester(address requester) external onlyAdmin {
        Status old = requesterStatus[requester];
        if (old != Status.Pending) revert UsersRequesterNotPending(requester, old);
        requesterStatus[requester] = Status.Active;
        emit RequesterApproved(requester, msg.sender);
        emit RequesterStatusUpdated(requester, Status.Active);
        emit RequesterAdded(requester);
    }

    /**
     * @dev Removes a requester for good: no new task or model request from it; its tasks
     * already posted run to their end (escrow, reviews and closing need no registration).
     * Requirements: caller is the requester itself or an admin; `requester` is Pending or
     * Active. Emits {RequesterRemoved} and {RequesterStatusUpdated} events.
     */
    function removeRequester(address requester) external {
        if (msg.sender != requester && !isAdmin[msg.sender]) revert UsersNotSelfOrAdmin(msg.sender, requester);
        Status old = requesterStatus[requester];
        if (old != Status.Pending && old != Status.Active) revert UsersRequesterNotRegistered(requester, old);
        requesterStatus[requester] = Status.Removed;
        emit RequesterRemoved(requester, msg.sender);
        emit RequesterStatusUpdated(requester, Status.Removed);
    }

    /// @dev True for an Active (registered and, where required, approved) requester.
    function isRequester(address account) external view returns (bool) {
        return requesterStatus[account] == Status.Active;
    }

    /**
     * @dev An approved worker switches between Active (takes offers) and Idle. Going Idle
     * leaves its domains' queues; going Active joins them at the tail (so the worker enters
     * a full pool behind the workers already waiting).
     * Requirements: caller is a worker, Active or Idle (approved, not removed); `status` is
     * Active or Idle. Emits a {WorkerStatusUpdated} event.
     */
    function updateStatus(Status status) external {
        uint32 id = _workerIdOf(msg.sender);
        if (status != Status.Active && status != Status.Idle) revert UsersBadStatus(uint8(status));
        Worker storage w = _workers[id];
        Status old = w.status;
        if (old != Status.Active && old != Status.Idle) revert UsersNotApproved(msg.sender, old);
        if (old != status) {
            w.status = status;
            if (status == Status.Active) _join(id, w.domains);
            else _leave(id, w.domains);
        }
        emit WorkerStatusUpdated(msg.sender, status);
    }

    /**
     * @dev A worker updates its computational capabilities (Comp. Capabilities, Table 7.2).
     * While {approvalRequired} is on, an approved (Active or Idle) worker whose capabilities
     * change is Pending again, out of its domains' queues, until an admin re-approves it
     * ({approveWorker}, which restores Active or Idle): capabilities rank workers (Eq. 20), so an
     * approval covers the ones declared. Unchanged values change nothing. A Pending worker
     * cannot change them while approval is required: the admin approves the values it
     * reviewed, not ones swapped in before the approval is mined. A removed worker cannot.
     * Requirements: caller is a worker, not Removed, not Pending with changed values while
     * {approvalRequired}. Emits a {WorkerCapabilitiesUpdated} event, and a
     * {WorkerStatusUpdated} event when the worker goes back to Pending.
     */
    function updateCapabilities(uint16 cpuCores, uint16 ramGb, uint8 gpuSeries) external {
        uint32 id = _workerIdOf(msg.sender);
        Worker storage w = _workers[id];
        Status old = w.status;
        bool changed = w.cpuCores != cpuCores || w.ramGb != ramGb || w.gpuSeries != gpuSeries;
        if (old == Status.Removed || (changed && approvalRequired && old == Status.Pending)) {
            revert UsersNotApproved(msg.sender, old);
        }
        (w.cpuCores, w.ramGb, w.gpuSeries) = (cpuCores, ramGb, gpuSeries);
        emit WorkerCapabilitiesUpdated(msg.sender, cpuCores, ramGb, gpuSeries);
        if (changed && approvalRequired && (old == Status.Active || old == Status.Idle)) {
            if (old == Status.Active) _leave(id, w.domains);
            else _idleOnApproval[id] = true;
            w.status = Status.Pending;
            emit WorkerStatusUpdated(msg.sender, Status.Pending);
        }
    }

    /**
     * @dev Performance details after a platform event (thesis updateInfo): increments the
     * counters selected by `flags` (ASSIGNED, ACCEPTED, COMPLETED, REVIEWED with `review`);
     * counters only grow (the TMC counts an offer once it is known to count, so none is ever
     * taken back). Requirements: caller is a platform contract (TMC, MMC); `worker` is a
     * worker; taskType TRAINING or SHARING; flags in 1..15; review <= 5;
     * completed <= accepted <= assigned afterwards.
     * Emits a {WorkerInfoUpdated} event with the new counters.
     */
    function updateInfo(address worker, uint32 domain, uint8 taskType, uint8 flags, uint8 review)
        external
    {
        if (!isPlatform[msg.sender]) revert UsersNotPlatform(msg.sender);
        _updateInfo(_workerIdOf(worker), worker, domain, taskType, flags, review);
    }

    /**
     * @dev {updateInfo} for the workers `ids` in order (an id may repeat: its counters move
     * once per entry), as many {updateInfo} calls would: the same checks, counters and one
     * {WorkerInfoUpdated} event per entry. One call instead of one per entry (the MMC's
     * allocation: its owners are known by id from the candidate pool, so no address lookup).
     * Returns the workers' addresses, in the order of `ids`.
     * Requirements: caller is a platform contract (TMC, MMC); every id is a registered worker;
     * taskType, flags and review as {updateInfo}.
     */
    function updateInfoBatch(uint32[] calldata ids, uint32 domain, uint8 taskType, uint8 flags, uint8 review)
        external
        returns (address[] memory workers)
    {
        if (!isPlatform[msg.sender]) revert UsersNotPlatform(msg.sender);
        workers = new address[](ids.length);
        for (uint256 i; i < ids.length; ++i) {
            uint32 id = ids[i];
            address worker = address(uint160(_rawWorker(id))); // 0 for id 0 and unused ids
            if (worker == address(0)) revert UsersNotWorkerId(id);
            workers[i] = worker;
            _updateInfo(id, worker, domain, taskType, flags, review);
        }
    }

    // ---------------------------------------------------------------------------- views

    /**
     * @dev Workers of `domain` in registration order (thesis getWorkers), one page: those at
     * positions [offset, offset + limit) of the domain's list ({domainSize} in all; a page
     * past the end is empty). Paged so that the view's gas is bounded by `limit`, not by the
     * number ever registered (an eth_call has a gas cap too).
     */
    function getWorkers(uint32 domain, uint256 offset, uint256 limit) external view returns (Worker[] memory out) {
        mapping(uint256 => uint256) storage list = _domainWorkers[domain];
        uint256 len = list[0] >> LIST_COUNT_SHIFT;
        uint256 n = offset < len ? len - offset : 0;
        if (n > limit) n = limit;
        out = new Worker[](n);
        uint256 word = 0;
        for (uint256 i; i < n; ++i) {
            uint256 j = offset + i; // < len <= 2^32
            uint256 e = j % LIST_PER_WORD;
            if (i == 0 || e == 0) word = list[j / LIST_PER_WORD];
            out[i] = _workers[uint32(word >> (32 * e))];
        }
    }

    /// @dev Counters of `worker` for (`domain`, `taskType`) (zeros for unknown workers).
    function counters(address worker, uint32 domain, uint8 taskType) external view returns (Counters memory) {
        return _counters[_key(workerId[worker], domain, taskType)];
    }

    function getWorker(address worker) external view returns (Worker memory) {
        return _workers[workerId[worker]];
    }

    /// @dev Domain bitmask of `worker` (0 for unknown addresses).
    function domainsOf(address worker) external view returns (uint256) {
        return _workers[workerId[worker]].domains;
    }

    function domainSize(uint32 domain) external view returns (uint256) {
        return _domainWorkers[domain][0] >> LIST_COUNT_SHIFT;
    }

    /**
     * @dev Candidate input for the TMC and MMC: for the workers of `domain`'s candidate pool
     * (the first {poolSize} of its Active queue, queue order), the packed worker word and
     * the packed counters of (`domain`, `taskType`). Packing (low bits first): worker = addr |
     * status << 160 | gpu << 168 | cores << 176 | ram << 192 | id << 208 | 1 << 255 (domain
     * member); counters = five 48-bit fields (assigned, accepted, completed, ratingSum,
     * ratingCount). Cost: at most MAX_POOL_SIZE candidates, whatever the number registered.
     */
    function candidates(uint32 domain, uint8 taskType)
        external
        view
        returns (uint256[] memory workers, uint256[] memory stats)
    {
        return _walkPool(domain, poolSize, taskType, true, true);
    }

    /**
     * @dev {candidates} without the worker words: the ids of `domain`'s candidate pool (the
     * same workers, same order) and, when `withCounters`, their packed counters of (`domain`,
     * `taskType`) (`stats` is empty otherwise). For the MMC, which ranks models by their
     * owner's id and counters only: one or two cold reads per candidate instead of three.
     */
    function candidateIds(uint32 domain, uint8 taskType, bool withCounters)
        external
        view
        returns (uint256[] memory ids, uint256[] memory stats)
    {
        return _walkPool(domain, poolSize, taskType, false, withCounters);
    }

    /// @dev Addresses of `domain`'s candidate pool (the first {poolSize} of its queue).
    function pool(uint32 domain) external view returns (address[] memory out) {
        return _queue(domain, poolSize);
    }

    /// @dev The whole Active queue of `domain` (pool first, then the waiting workers).
    function queue(uint32 domain) external view returns (address[] memory out) {
        return _queue(domain, type(uint256).max);
    }

    /// @dev Number of workers in `domain`'s Active queue (pool and waiting).
    function queueLength(uint32 domain) external view returns (uint256) {
        return _queues[domain] >> 64;
    }

    /// @dev The worker id of `account` and its storage word (addr | status << 160 | gpu << 168
    /// | cores << 176 | ram << 192 | domains << 208); zeros for unknown addresses.
    function workerRecord(address account) external view returns (uint32 id, uint256 word) {
        id = workerId[account];
        word = _rawWorker(id);
    }

    /**
     * @dev The same packed words for workers given by id (model owners, Eq. 23); bit 255 of
     * the worker word is set when the worker covers `domain`. Id 0 gives zero words.
     */
    function profiles(uint32[] calldata ids, uint32 domain, uint8 taskType)
        external
        view
        returns (uint256[] memory workers, uint256[] memory stats)
    {
        uint256 n = ids.length;
        workers = new uint256[](n);
        stats = new uint256[](n);
        for (uint256 i; i < n; ++i) {
            uint32 id = ids[i];
            if (id == 0) continue;
            uint256 raw = _rawWorker(id);
            uint256 word = raw & WORKER_FIELDS;
            if (domain <= MAX_DOMAIN && (raw >> (DOMAINS_SHIFT + domain)) & 1 == 1) word |= MEMBER_BIT;
            workers[i] = word;
            stats[i] = _rawCounters(_key(id, domain, taskType));
        }
    }

    // ---------------------------------------------------------------------------- internal

    /// @dev Appends worker `id` to the tail of the queue of every domain in `domains`.
    function _join(uint32 id, uint256 domains) internal {
        uint256 rest = domains;
        while (rest != 0) {
            uint256 low = rest & (~rest + 1);
            rest ^= low;
            uint256 d = Math.log2(low);
            uint256 q = _queues[d];
            uint256 tail = (q >> 32) & ID_MASK;
            if (tail == 0) {
                // prev = next = none: the link is already zero (never set, or deleted by
                // _leave), so it is not written.
                q = id | (uint256(id) << 32) | (1 << 64);
            } else {
                _links[(d << 32) | id] = tail; // prev = old tail, next = none
                _links[(d << 32) | tail] |= uint256(id) << 32;
                q = (q & ~(ID_MASK << 32)) + (uint256(id) << 32) + (1 << 64);
            }
            _queues[d] = q;
        }
    }

    /// @dev Appends worker `id` to the registration list of domain `d`.
    function _listWorker(uint256 d, uint32 id) internal {
        uint256 head = _domainWorkers[d][0];
        uint256 n = head >> LIST_COUNT_SHIFT; // < 2^32: at most workerCount entries
        uint256 entry = uint256(id) << (32 * (n % LIST_PER_WORD));
        if (n < LIST_PER_WORD) {
            _domainWorkers[d][0] = (head + (1 << LIST_COUNT_SHIFT)) | entry;
        } else {
            _domainWorkers[d][0] = head + (1 << LIST_COUNT_SHIFT);
            _domainWorkers[d][n / LIST_PER_WORD] |= entry;
        }
    }

    /// @dev Unlinks worker `id` from the queue of every domain in `domains`.
    function _leave(uint32 id, uint256 domains) internal {
        uint256 rest = domains;
        while (rest != 0) {
            uint256 low = rest & (~rest + 1);
            rest ^= low;
            uint256 d = Math.log2(low);
            uint256 node = _links[(d << 32) | id];
            uint256 prev = node & ID_MASK;
            uint256 next = (node >> 32) & ID_MASK;
            uint256 q = _queues[d];
            if (prev == 0) q = (q & ~ID_MASK) | next;
            else _links[(d << 32) | prev] = (_links[(d << 32) | prev] & ID_MASK) | (next << 32);
            if (next == 0) q = (q & ~(ID_MASK << 32)) | (prev << 32);
            else _links[(d << 32) | next] = (_links[(d << 32) | next] & ~ID_MASK) | prev;
            delete _links[(d << 32) | id];
            _queues[d] = q - (1 << 64);
        }
    }

    function _queue(uint32 domain, uint256 limit) internal view returns (address[] memory out) {
        (uint256[] memory ids,) = _walkPool(domain, limit, 0, false, false);
        uint256 n = ids.length;
        out = new address[](n);
        for (uint256 i; i < n; ++i) {
            out[i] = _workers[uint32(ids[i])].addr;
        }
    }

    /// @dev The one walk of `domain`'s Active queue links that every pool and queue view
    /// shares: for its first `limit` workers in queue order, their ids, or with `words` their
    /// candidate words ({candidates}' packing), and with `withCounters` their packed counters of
    /// (`domain`, `taskType`) (`stats` is empty otherwise). One pass, no second array walk:
    /// the allocations call it with a pool of up to MAX_POOL_SIZE.
    function _walkPool(uint32 domain, uint256 limit, uint8 taskType, bool words, bool withCounters)
        internal
        view
        returns (uint256[] memory out, uint256[] memory stats)
    {
        uint256 q = _queues[domain];
        uint256 n = q >> 64;
        if (n > limit) n = limit;
        out = new uint256[](n);
        stats = new uint256[](withCounters ? n : 0);
        uint256 id = q & ID_MASK;
        for (uint256 i; i < n; ++i) {
            out[i] = words ? (_rawWorker(uint32(id)) & WORKER_FIELDS) | (id << ID_SHIFT) | MEMBER_BIT : id;
            if (withCounters) stats[i] = _rawCounters(_key(uint32(id), domain, taskType));
            id = _links[(uint256(domain) << 32) | id] >> 32;
        }
    }

    /// @dev The counter update of {updateInfo} for worker `id` (address `worker`).
    function _updateInfo(uint32 id, address worker, uint32 domain, uint8 taskType, uint8 flags, uint8 review)
        internal
    {
        if (taskType > SHARING) revert UsersBadTaskType(taskType);
        if (flags == 0 || flags > 15) revert UsersBadFlags(flags);
        Counters memory c = _counters[_key(id, domain, taskType)];
        unchecked {
            // uint48 counters: 2.8e14 events per worker before wrapping.
            if (flags & ASSIGNED != 0) ++c.assigned;
            if (flags & ACCEPTED != 0) ++c.accepted;
            if (flags & COMPLETED != 0) ++c.completed;
            if (flags & REVIEWED != 0) {
                if (review > REVIEW_MAX) revert UsersBadReview(review);
                c.ratingSum += review;
                ++c.ratingCount;
            }
        }
        if (c.completed > c.accepted || c.accepted > c.assigned) {
            revert UsersCountersInconsistent(worker, domain, taskType);
        }
        _counters[_key(id, domain, taskType)] = c;
        emit WorkerInfoUpdated(worker, domain, taskType, c.assigned, c.accepted, c.completed, c.ratingSum, c.ratingCount);
    }

    /// @dev Records the caller's vote for the change; whether it now has the quorum. With
    /// one admin nothing is stored: its vote is the quorum.
    function _voteCarries(uint8 kind, address account, bool on) internal returns (bool) {
        uint256 needed = quorum();
        if (needed == 1) return true;
        bytes32 proposal = changeProposal(kind, account, on);
        if (hasVoted[proposal][msg.sender]) revert UsersAlreadyVoted(msg.sender, proposal);
        hasVoted[proposal][msg.sender] = true;
        uint256 votes = changeVotes[proposal] + 1;
        changeVotes[proposal] = votes;
        emit ChangeVoted(proposal, msg.sender, kind, account, on, votes, needed);
        return votes >= needed;
    }

    function _checkAdmin() internal view {
        if (!isAdmin[msg.sender]) revert UsersNotAdmin(msg.sender);
    }

    /// @dev The storage word of worker `id`: its layout (addr | status << 160 | gpu << 168 |
    /// cores << 176 | ram << 192 | domains << 208) is the packed format itself, so scans copy
    /// it without decoding the struct (~1.5k gas less per candidate).
    function _rawWorker(uint32 id) internal view returns (uint256 w) {
        assembly {
            mstore(0, id)
            mstore(32, _workers.slot)
            w := sload(keccak256(0, 64))
        }
    }

    /// @dev The storage word of a counter set (five uint48 from the low bits = packed format).
    function _rawCounters(uint256 key) internal view returns (uint256 c) {
        assembly {
            mstore(0, key)
            mstore(32, _counters.slot)
            c := sload(keccak256(0, 64))
        }
    }

    function _workerIdOf(address account) internal view returns (uint32 id) {
        id = workerId[account];
        if (id == 0) revert UsersNotWorker(account);
    }

    function _key(uint32 id, uint32 domain, uint8 taskType) internal pure returns (uint256) {
        return (uint256(id) << 40) | (uint256(domain) << 8) | taskType;
    }
}
