// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

import {ReentrancyGuardTransient} from "@openzeppelin/contracts/utils/ReentrancyGuardTransient.sol";
import {IUsersManager, Packed} from "./IUsersManager.sol";
import {ITasksOutcomes} from "./ITasksOutcomes.sol";
import {IModelsListing} from "./IModelsListing.sol";
import {QoSMath} from "./QoSMath.sol";
import {CidText} from "./CidText.sol";

/**
 * @title TasksManager (TMC, thesis Table 7.3)
 * @dev DRL training tasks: escrowed payment at {addTask}, greedy QoS recruitment (Eq. 16-21,
 * thesis 7.6) in {allocateTask}, offers accepted or declined within an acceptance window, an
 * expired or declined offer handed to the next best eligible worker by calling
 * {allocateTask} again, outcomes (IPFS CIDs) submitted before the deadline, one review per
 * outcome, pull payments. Model-sharing requests go to the MMC.
 *
 * Payment: `reward` per worker slot is escrowed for `numWorkers` slots. Every slot is settled
 * exactly once: credited to the worker for an accepted outcome (or an outcome left
 * unreviewed past the review window), or refunded to the requester (rejected outcome,
 * cancellation, slots still unfilled at close). Credits are withdrawn with {withdraw}
 * (checks-effects-interactions plus a transient reentrancy guard).
 *
 * Anti-spam: a consortium admin sets {minRewardPerHour}, the least reward per worker-hour a
 * task may offer ({addTask} reverts below it). A task always pays at least 1 wei per worker,
 * even with no minimum set: a zero-reward task costs its requester nothing (the escrow comes
 * back at close) yet could make offers to any worker (docs/chain.md, "Offers a worker can
 * take").
 *
 * Offers a worker can take (anti-griefing): no offer may be made that the worker could not
 * accept and complete. {addTask} requires duration >= acceptWindow + {minWorkTime}, and
 * {allocateTask} refuses once now + acceptWindow + minWorkTime > deadline: a worker accepting
 * at the very end of its window still has minWorkTime to train.
 *
 * Offers that count (A of Eq. 17): an offer counts as assigned only once it is known whether
 * it should. An accepted offer counts at {acceptOffer} (assigned and accepted at once); an
 * offer never accepted (declined or expired) counts when its task ends (closed, cancelled or
 * completed), and only if some worker still held a slot of the task then (`filled` != 0: the
 * task was worth taking, the offeree lost it to someone else). Offers of a task still running,
 * or of one nobody held at its end, never lower anyone's reputation: a requester cannot make
 * decoy offers a weapon (docs/chain.md, "Offers that count").
 *
 * Bounded escrow: duration <= {maxDuration} (admin-set), and the requester may cancel the
 * slots nobody holds at any time ({cancelOpenSlots}); only the slots of workers who accepted
 * stay escrowed until the deadline. An accepted worker who never submits keeps its slot until
 * the deadline the requester chose (there is no on-chain evidence of progress that would let
 * a requester take it back without letting requesters grief workers); it can give the slot
 * back with {abandonOffer}, and at close the slot is refunded and the worker's reputation
 * drops (accepted, never completed).
 *
 * Reviews: the requester reviews each outcome until the task's review end, deadline +
 * reviewWindow as configured when the task was posted ({Reqs.reviewEnd}: a later
 * {setConfig} changes no posted task); after that the outcome is the worker's (paid at
 * close) and {reviewOutcome} reverts. reviewWindow <= {MAX_REVIEW_WINDOW}.
 *
 * Sealed outcomes: an outcome CID is public once submitted, before the requester pays; with
 * the spec's outcome_key the worker uploads the weights only sealed to the requester's key,
 * so the CID (the plaintext bundle's) opens the card for anyone and the weights for the
 * requester only. Key release against payment was decided against: the contract cannot check
 * a wrapped key (docs/chain.md, "Outcomes are public before payment").
 *
 * Recruitment decisions (docs/chain.md): the accepted GPU series are one consortium policy
 * ({acceptedGpus}: which hardware the consortium trusts), while a task's own compute needs
 * are its minCpuCores / minRamGb; capabilities are self-declared by workers (overclaiming
 * makes jobs fail, which Eq. 18 punishes); Eq. 16 is as in the thesis here (a new worker's
 * expertise is 0 once anyone completed a task; the decided pseudo-count is documented).
 *
 * EVM: {withdraw}'s reentrancy guard uses transient storage (EIP-1153), so the chain must
 * run Cancun or later (genesis cancunTime / Besu "cancunTime": 0; the deploy/ genesis must enable it).
 *
 * Provenance: every outcome CID is recorded once, with its worker and task ({outcomeOf},
 * keyed by keccak256 of the CID); the MMC lets only that worker share it, once accepted.
 *
 * Commit-reveal of CIDs: a CID is public from the moment its transaction is pending, so
 * whoever saw it could hand it in first (as an outcome of a task it posted from a second
 * address, or as its own model), and the duplicate rules would then refuse its producer. A
 * worker therefore commits {cidCommitment}(cid, itself) with {commitCid} before the CID is
 * published (before the upload) and reveals it with {submitOutcome} (or the MMC's addModel)
 * in a later block. A copier sees the CID only in the reveal; its own commitment would be
 * mined in that block or later, so its reveal comes after the producer's.
 *
 * Text (description, outcome CIDs) lives only in events: the indexer keeps it, the chain
 * keeps what the rules need (~20k gas saved per 32 bytes not stored).
 */
contract TasksManager is ITasksOutcomes, ReentrancyGuardTransient {
    using Packed for uint256;

    uint8 internal constant TRAINING = 0;
    uint8 internal constant ASSIGNED = 1;
    uint8 internal constant ACCEPTED = 2;
    uint8 internal constant COMPLETED = 4;
    uint8 internal constant REVIEWED = 8;
    uint256 public constant MAX_WORKERS = 16; // NW fits uint8 and keeps the top-k array tiny
    uint256 public constant MAX_OFFERS = 64; // bounds the per-task offer loops
    uint256 internal constant ELIGIBLE = 1 << 255;
    uint32 public constant DEFAULT_MIN_WORK_TIME = 60; // a floor; the consortium sets its own
    uint40 public constant DEFAULT_MAX_DURATION = 30 days;
    /// Longest review window {setConfig} accepts: bounds how long a worker's pay for an
    /// unreviewed outcome can wait after the deadline.
    uint32 public constant MAX_REVIEW_WINDOW = 90 days;
    uint256 internal constant ID_MASK = (1 << 32) - 1;
    /// Longest task description {addTask} takes (bytes): the gateway's is the spec's CID (at
    /// most 128 characters) and a model's description is at most 1,024 characters, 4 bytes
    /// each in UTF-8 at most (docs/chain.md, "Held-out pass of 2026-12-05, second").
    uint256 public constant MAX_DESCRIPTION_BYTES = 4096;
    /// Commitments {commitCid} keeps per worker: its last MAX_LIVE_COMMITMENTS, in a ring; a
    /// newer one evicts the oldest still unspent ({CidCommitmentEvicted}), so a worker's
    /// commitments take at most this many slots (and as many ring slots) whatever it commits.
    uint256 public constant MAX_LIVE_COMMITMENTS = 16;

    enum TaskStatus {
        None,
        Open,
        Completed,
        Cancelled,
        Closed
    }

    enum OfferState {
        None,
        Offered,
        Accepted,
        Declined,
        Expired,
        Submitted,
        Reviewed,
        Failed
    }

    /// One slot: who, state, slot counters and deadline.
    struct Task {
        address requester;
        TaskStatus status;
        uint8 numWorkers;
        uint8 liveOffers; // offers not yet accepted, declined or expired
        uint8 filled; // workers holding a slot: accepted, not given back ({abandonOffer})
        uint8 settled; // slots paid or refunded
        uint8 offerCount; // offers ever made (<= MAX_OFFERS)
        uint40 deadline;
    }

    /// One slot: the requirements of 7.5.1, the reward per worker and the review end.
    /// Domain (<= 47) and thresholds (<= 1e6) are stored narrower than {TaskParams} takes them
    /// (both checked by {addTask}) to leave room for `reviewEnd`.
    struct Reqs {
        uint8 domain;
        uint24 minReputation;
        uint24 minRating;
        uint32 minCpuCores;
        uint32 minRamGb;
        uint96 reward;
        uint40 reviewEnd; // deadline + reviewWindow when posted: reviews until, pay after
    }

    struct Offer {
        OfferState state;
        uint40 expiry;
        uint32 workerId; // the offeree's UMC worker id
        bool paid; // Reviewed only: the outcome was accepted (or paid unreviewed at close)
    }

    /// Who submitted an outcome CID, for which task (one slot).
    struct OutcomeRecord {
        address worker;
        uint64 taskId;
    }

    struct TaskParams {
        uint32 domain;
        uint8 numWorkers;
        uint32 minReputation;
        uint32 minRating;
        uint32 minCpuCores;
        uint32 minRamGb;
        uint40 duration;
        string description;
    }

    error TasksNotAdmin(address account);
    error TasksNotRequester(address account);
    error TasksUnknownTask(uint256 taskId);
    error TasksNotTaskRequester(uint256 taskId, address account);
    error TasksNotParticipant(uint256 taskId, address account);
    error TasksBadWorkerCount(uint8 numWorkers);
    error TasksBadDomain(uint32 domain);
    error TasksBadThreshold(uint32 value);
    error TasksBadDuration(uint40 duration, uint256 minimum, uint256 maximum);
    error TasksTooLateToOffer(uint256 taskId, uint40 deadline);
    error TasksReviewWindowClosed(uint256 taskId, uint256 reviewEnd);
    error TasksBadPayment(uint256 value, uint8 numWorkers);
    error TasksDescriptionTooLong(uint256 length, uint256 maximum);
    error TasksNotOpen(uint256 taskId, TaskStatus status);
    error TasksDeadlinePassed(uint256 taskId, uint40 deadline);
    error TasksDeadlineNotPassed(uint256 taskId, uint40 deadline);
    error TasksNoOpenSlot(uint256 taskId);
    error TasksOfferLimitReached(uint256 taskId);
    error TasksNotOfferedWorker(uint256 taskId, address worker);
    error TasksOfferExpired(uint256 taskId, address worker, uint40 expiry);
    error TasksNotAssignedWorker(uint256 taskId, address worker);
    error TasksNotSubmitted(uint256 taskId, address worker);
    error TasksEmptyCid();
    /// The CID is not in the one text form the chain records (lowercase base32 CIDv1).
    error TasksCidNotCanonical(string cid);
    error TasksDuplicateOutcome(uint256 taskId, address worker);
    error TasksOutcomeIsListedModel(uint256 modelId);
    error TasksNotWorker(address account);
    error TasksCidNotCommitted(bytes32 commitment);
    error TasksModelsAlreadySet(address models);
    error TasksRewardBelowMinimum(uint256 reward, uint256 minimum);
    error TasksBadReview(uint8 review);
    error TasksHasAcceptedWorkers(uint256 taskId);
    error TasksHasLiveOffers(uint256 taskId);
    error TasksReviewWindowOpen(uint256 taskId, uint256 until);
    error TasksBadStatus(TaskStatus status);
    error TasksBadConfig();
    error TasksNothingToWithdraw(address account);
    error TasksTransferFailed(address account, uint256 amount);

    event TaskAdded(
        uint256 indexed taskId,
        address indexed requester,
        uint32 indexed domain,
        uint8 numWorkers,
        uint96 reward,
        uint40 deadline,
        uint32 minReputation,
        uint32 minRating,
        uint32 minCpuCores,
        uint32 minRamGb,
        string description
    );
    event TaskOffered(uint256 indexed taskId, address indexed worker, uint256 qos, uint40 expiry);
    event TaskAllocated(uint256 indexed taskId, uint256 offered);
    event OfferAccepted(uint256 indexed taskId, address indexed worker);
    event OfferDeclined(uint256 indexed taskId, address indexed worker);
    event OfferExpired(uint256 indexed taskId, address indexed worker);
    event OfferFailed(uint256 indexed taskId, address indexed worker);
    event OutcomeSubmitted(uint256 indexed taskId, address indexed worker, string cid);
    event OutcomeReviewed(uint256 indexed taskId, address indexed worker, uint8 review, bool accepted);
    /// An outcome the requester did not review within the task's review window, paid to its
    /// worker at close: completed, with no review (not a review of 0).
    event OutcomePaidUnreviewed(uint256 indexed taskId, address indexed worker);
    event TaskStatusUpdated(uint256 indexed taskId, TaskStatus status);
    event PaymentCredited(address indexed account, uint256 indexed taskId, uint256 amount);
    event Withdrawn(address indexed account, uint256 amount);
    event ConfigUpdated(uint64 w1, uint32 acceptWindow, uint32 reviewWindow);
    event AcceptedGpusUpdated(uint256 mask);
    event MinRewardPerHourUpdated(uint256 weiPerHour);
    event TaskLimitsUpdated(uint32 minWorkTime, uint40 maxDuration);
    event SlotsCancelled(uint256 indexed taskId, uint8 cancelled, uint8 numWorkers);
    event ModelsListingSet(address models);
    event CidCommitted(address indexed worker, bytes32 indexed commitment);
    /// A worker's commitment made MAX_LIVE_COMMITMENTS commitments ago and not spent, dropped
    /// by its newer one (it reveals nothing any more: commit again).
    event CidCommitmentEvicted(address indexed worker, bytes32 indexed commitment);

    IUsersManager public immutable umc;
    /// The MMC, set once by an admin after both are deployed (each names the other).
    IModelsListing public models;

    /// Admin-set parameters (one slot): Eq. 20 weight w1 (scaled by 1e6), windows in seconds.
    uint64 public w1;
    uint32 public acceptWindow;
    uint32 public reviewWindow;
    /// Least time (s) an offered worker has to train after its acceptance window ends.
    uint32 public minWorkTime;
    /// Longest task duration (s) {addTask} accepts: bounds how long escrow can stay locked.
    /// Packed with w1 and the windows: {allocateTask} reads all four in one SLOAD.
    uint40 public maxDuration;
    /// Accepted GPU series (7.5.1) as a bitmask of codes 0-255: one SLOAD for all candidates.
    uint256 public acceptedGpus;
    uint256 public taskCount;
    /// Least reward per worker-hour (wei) a task may offer; 0 = no minimum. Admin-set.
    uint256 public minRewardPerHour;

    mapping(uint256 => Task) internal _tasks;
    mapping(uint256 => Reqs) internal _reqs;
    mapping(uint256 => address[]) internal _offerees;
    mapping(uint256 => mapping(address => Offer)) internal _offers;
    /// Domain Tasks (thesis: uint -> Task[]), as task ids.
    mapping(uint32 => uint256[]) internal _domainTasks;
    /// Pull payments: native currency owed to each account.
    mapping(address => uint256) public credits;
    /// Outcome provenance: keccak256(cid) -> submitting worker and task.
    mapping(bytes32 => OutcomeRecord) internal _outcomes;
    /// @dev Each live {cidCommitment} ({commitCid}): the block it was committed in (bits
    /// 0-63, {cidCommits}), its committer's UMC worker id (64-95) and its position in that
    /// worker's ring (96-103); 0 if never committed, spent or evicted.
    mapping(bytes32 commitment => uint256 record) internal _commits;
    /// @dev Per worker id, its last MAX_LIVE_COMMITMENTS commitments by ring position.
    mapping(uint32 workerId => mapping(uint256 position => bytes32 commitment)) internal _commitRing;
    /// @dev Per worker id, the commitments it made in all (its next ring position mod
    /// MAX_LIVE_COMMITMENTS).
    mapping(uint32 workerId => uint256 made) internal _commitsMade;

    constructor(IUsersManager umc_, uint64 w1_, uint32 acceptWindow_, uint32 reviewWindow_, uint256 gpus) {
        umc = umc_;
        (minWorkTime, maxDuration) = (DEFAULT_MIN_WORK_TIME, DEFAULT_MAX_DURATION);
        emit TaskLimitsUpdated(DEFAULT_MIN_WORK_TIME, DEFAULT_MAX_DURATION);
        _setConfig(w1_, acceptWindow_, reviewWindow_);
        acceptedGpus = gpus;
        emit AcceptedGpusUpdated(gpus);
    }

    // ---------------------------------------------------------------------------- admin

    /**
     * @dev Sets w1 (Eq. 20, scaled by 1e6, in [1, 1e12]) and the acceptance and review
     * windows (seconds, > 0). The review window applies to tasks posted afterwards: each task
     * keeps the review end fixed when it was posted, so an admin can neither shorten a running
     * task's review nor hold its workers' pay longer. Requirements: caller is a consortium
     * admin; acceptWindow + minWorkTime <= maxDuration; reviewWindow <= {MAX_REVIEW_WINDOW}.
     * Emits a {ConfigUpdated} event.
     */
    function setConfig(uint64 w1_, uint32 acceptWindow_, uint32 reviewWindow_) external {
        _checkAdmin();
        _setConfig(w1_, acceptWindow_, reviewWindow_);
    }

    /**
     * @dev Adds or removes a GPU series from the accepted list (7.5.1).
     * Requirements: caller is a consortium admin. Emits an {AcceptedGpusUpdated} event
     * with the whole new mask (bit s = series s accepted).
     */
    function setGpuSeries(uint8 series, bool accepted) external {
        _checkAdmin();
        uint256 mask = acceptedGpus;
        mask = accepted ? mask | (uint256(1) << series) : mask & ~(uint256(1) << series);
        acceptedGpus = mask;
        emit AcceptedGpusUpdated(mask);
    }

    /**
     * @dev Names the MMC whose listed CIDs {submitOutcome} refuses, once (the MMC is deployed
     * after the TMC, with its address). Requirements: caller is a consortium admin; not set
     * before; a nonzero address. Emits a {ModelsListingSet} event.
     */
    function setModels(IModelsListing models_) external {
        _checkAdmin();
        if (address(models) != address(0)) revert TasksModelsAlreadySet(address(models));
        if (address(models_) == address(0)) revert TasksBadConfig();
        models = models_;
        emit ModelsListingSet(address(models_));
    }

    /**
     * @dev Sets the task time limits: `minWorkTime_` (s, > 0), the least time a worker has
     * after its acceptance window before the deadline, and `maxDuration_` (s, < 2^32), the
     * longest duration {addTask} accepts. Tasks already posted keep their deadline; an
     * {allocateTask} checks the limits in force when it runs.
     * Requirements: caller is a consortium admin; acceptWindow + minWorkTime_ <= maxDuration_.
     * Emits a {TaskLimitsUpdated} event.
     */
    function setTaskLimits(uint32 minWorkTime_, uint40 maxDuration_) external {
        _checkAdmin();
        _checkLimits(acceptWindow, minWorkTime_, maxDuration_);
        (minWorkTime, maxDuration) = (minWorkTime_, maxDuration_);
        emit TaskLimitsUpdated(minWorkTime_, maxDuration_);
    }

    /**
     * @dev Sets the least reward per worker-hour (wei) that {addTask} accepts; 0 leaves only
     * the floor of 1 wei per worker. Requirements: caller is a consortium admin; weiPerHour < 2^96 (rewards are
     * uint96). Emits a {MinRewardPerHourUpdated} event.
     */
    function setMinRewardPerHour(uint256 weiPerHour) external {
        _checkAdmin();
        if (weiPerHour > type(uint96).max) revert TasksBadConfig();
        minRewardPerHour = weiPerHour;
        emit MinRewardPerHourUpdated(weiPerHour);
    }

    // ---------------------------------------------------------------------------- requester

    /**
     * @dev Creates a training task and escrows `msg.value` = reward * numWorkers.
     * Requirements: caller is a registered requester; a description of at most
     * {MAX_DESCRIPTION_BYTES} bytes; 1 <= numWorkers <= 16; domain <= 47;
     * thresholds <= 1e6; acceptWindow + minWorkTime <= duration <= maxDuration (s);
     * msg.value a multiple of numWorkers; the reward per worker at least
     * {minRewardForDuration}(duration), i.e. minRewardPerHour per hour of the task's duration
     * (deadline - now), rounded up to the wei, and at least 1 wei. The task's review end is
     * fixed here (deadline + the current reviewWindow; {getTask}'s `reviewEnd`).
     * Emits a {TaskAdded} event.
     */
    function addTask(TaskParams calldata p) external payable returns (uint256 taskId) {
        if (!umc.isRequester(msg.sender)) revert TasksNotRequester(msg.sender);
        if (bytes(p.description).length > MAX_DESCRIPTION_BYTES) {
            revert TasksDescriptionTooLong(bytes(p.description).length, MAX_DESCRIPTION_BYTES);
        }
        if (p.numWorkers == 0 || p.numWorkers > MAX_WORKERS) revert TasksBadWorkerCount(p.numWorkers);
        if (p.domain > Packed.MAX_DOMAIN) revert TasksBadDomain(p.domain);
        if (p.minReputation > QoSMath.ONE) revert TasksBadThreshold(p.minReputation);
        if (p.minRating > QoSMath.ONE) revert TasksBadThreshold(p.minRating);
        uint256 shortest = uint256(acceptWindow) + minWorkTime;
        if (p.duration < shortest || p.duration > maxDuration) {
            revert TasksBadDuration(p.duration, shortest, maxDuration);
        }
        // Exact division, checked right below (reward * NW == msg.value): nothing is lost.
        // slither-disable-next-line divide-before-multiply
        uint256 reward = msg.value / p.numWorkers;
        if (reward * p.numWorkers != msg.value || reward > type(uint96).max) {
            revert TasksBadPayment(msg.value, p.numWorkers);
        }
        uint256 minimum = minRewardForDuration(p.duration);
        if (reward < minimum) revert TasksRewardBelowMinimum(reward, minimum);
        taskId = ++taskCount;
        uint40 deadline = uint40(block.timestamp) + p.duration;
        _tasks[taskId] = Task(msg.sender, TaskStatus.Open, p.numWorkers, 0, 0, 0, 0, deadline);
        _reqs[taskId] = Reqs(
            uint8(p.domain),
            uint24(p.minReputation),
            uint24(p.minRating),
            p.minCpuCores,
            p.minRamGb,
            uint96(reward),
            deadline + reviewWindow
        );
        _domainTasks[p.domain].push(taskId);
        emit TaskAdded(
            taskId,
            msg.sender,
            p.domain,
            p.numWorkers,
            uint96(reward),
            deadline,
            p.minReputation,
            p.minRating,
            p.minCpuCores,
            p.minRamGb,
            p.description
        );
    }

    /**
     * @dev Recruits workers for the open slots (thesis 7.6): expires offers past their
     * acceptance window, then offers the task to the best eligible workers by Eq. 21 QoS,
     * excluding everyone offered this task before (the "next best" after an expiry) and
     * the requester itself. The candidates are the domain's candidate pool of the UMC (at
     * most UMC.MAX_POOL_SIZE approved Active workers, see UsersManager), so the cost does not
     * grow with the number of registered workers; equal QoS goes to the lower worker id
     * (earlier registration).
     * Requirements: caller is the task's requester or an admin; task open;
     * now + acceptWindow + minWorkTime <= deadline (an offered worker can accept and still
     * has minWorkTime to train); at least one open slot; fewer than MAX_OFFERS offers made.
     * No counter moves: an offer counts in A of Eq. 17 once accepted, or at the task's end
     * (docs/chain.md, "Offers that count").
     * Emits {OfferExpired}, {TaskOffered} per offer and one {TaskAllocated} event.
     */
    function allocateTask(uint256 taskId) external returns (uint256 offered) {
        Task storage t = _tasks[taskId];
        if (t.requester != msg.sender && !umc.isAdmin(msg.sender)) _checkRequester(t, taskId);
        _checkOpen(t, taskId);
        if (block.timestamp + acceptWindow + minWorkTime > t.deadline) {
            revert TasksTooLateToOffer(taskId, t.deadline);
        }
        Reqs memory r = _reqs[taskId];
        (uint256[] memory ws, uint256[] memory cs) = umc.candidates(r.domain, TRAINING);
        (uint256 live, address[] memory skip) = _expireOffers(taskId, t.requester);
        uint256 open = t.numWorkers - live - t.filled;
        if (open == 0) revert TasksNoOpenSlot(taskId);
        uint256 room = MAX_OFFERS - t.offerCount;
        if (room == 0) revert TasksOfferLimitReached(taskId);
        if (open > room) open = room;

        (uint256[] memory idx, uint256[] memory qs, uint256 count) = _select(r, ws, cs, skip, open);
        uint40 expiry = uint40(block.timestamp) + acceptWindow;
        for (uint256 i; i < count; ++i) {
            uint256 w = ws[idx[i]];
            address a = w.addr();
            _offers[taskId][a] = Offer(OfferState.Offered, expiry, w.id(), false);
            _offerees[taskId].push(a);
            emit TaskOffered(taskId, a, qs[i] >> 32, expiry);
        }
        t.liveOffers = uint8(live + count);
        t.offerCount += uint8(count);
        emit TaskAllocated(taskId, count);
        return count;
    }

    /**
     * @dev The requester reviews a submitted outcome once: `review` in [0, 5] feeds the
     * worker's rating; `accepted` releases the slot's reward to the worker and counts the
     * task as completed (E of Eq. 18, N of Eq. 16), otherwise the reward is refunded and the
     * task does not count as completed. The review of the last slot completes the task: its
     * offers never accepted then count as assigned (the task found workers).
     * Requirements: caller is the task's requester; the worker's outcome is submitted and not
     * yet reviewed; now <= the task's review end (deadline + the reviewWindow of when it was
     * posted; afterwards the outcome is the worker's: paid at close); review <= 5.
     * Emits {OutcomeReviewed}, {PaymentCredited} and, on the last slot, {TaskStatusUpdated}.
     */
    function reviewOutcome(uint256 taskId, address worker, uint8 review, bool accepted) external {
        Task storage t = _tasks[taskId];
        _checkRequester(t, taskId);
        Offer storage o = _offers[taskId][worker];
        if (o.state != OfferState.Submitted) revert TasksNotSubmitted(taskId, worker);
        Reqs storage r = _reqs[taskId];
        uint256 reviewEnd = r.reviewEnd;
        if (block.timestamp > reviewEnd) revert TasksReviewWindowClosed(taskId, reviewEnd);
        if (review > QoSMath.REVIEW_MAX) revert TasksBadReview(review);
        o.state = OfferState.Reviewed;
        o.paid = accepted;
        _credit(accepted ? worker : t.requester, taskId, r.reward);
        uint8 settled = t.settled + 1;
        t.settled = settled;
        uint8[] memory counted = new uint8[](0);
        if (settled == t.numWorkers) {
            t.status = TaskStatus.Completed;
            emit TaskStatusUpdated(taskId, TaskStatus.Completed);
            counted = _unaccepted(taskId, t); // this worker holds a slot: filled != 0
        }
        // interactions last: every state change is written
        // a rejected outcome is rated but not completed (E of Eq. 18, N of Eq. 16)
        umc.updateInfo(worker, r.domain, TRAINING, accepted ? COMPLETED | REVIEWED : REVIEWED, review);
        emit OutcomeReviewed(taskId, worker, review, accepted);
        _count(taskId, counted);
    }

    /**
     * @dev Task status changes (thesis updateTaskStatus):
     * - Cancelled: by the requester while open, before any worker accepted and with no offer
     *   inside its acceptance window (an offered worker keeps its chance to accept);
     *   offers past their window expire with it
     *   ({OfferExpired} each, as at close); refunds all. With workers holding slots, use
     *   {cancelOpenSlots} to refund the rest.
     * - Closed: after the deadline, by the requester, an admin or any worker offered the
     *   task. Outcomes submitted but not reviewed are paid and count as completed (if the
     *   review window is over; otherwise the call reverts), accepted offers without outcome
     *   become Failed and are rated 0, pending offers Expired, and the unsettled slots are
     *   refunded to the requester. The offers never accepted (declined, expired) then count
     *   as assigned (A of Eq. 17) if a worker still held a slot ({Task.filled} != 0).
     * - A cancel moves no counter: no worker holds a slot, so its offers never count.
     * Emits {TaskStatusUpdated}, {PaymentCredited} and per-offer events.
     */
    function updateTaskStatus(uint256 taskId, TaskStatus status) external {
        Task storage t = _tasks[taskId];
        if (t.status == TaskStatus.None) revert TasksUnknownTask(taskId);
        uint8[] memory counted = new uint8[](0); // per offeree: UMC flags, moved once settled
        if (status == TaskStatus.Cancelled) {
            _checkRequester(t, taskId);
            _checkOpen(t, taskId);
            if (t.filled != 0) revert TasksHasAcceptedWorkers(taskId);
            if (t.liveOffers != 0) {
                // offers past their acceptance window expire with the task (OfferExpired each)
                (uint256 live,) = _expireOffers(taskId, t.requester);
                if (live != 0) revert TasksHasLiveOffers(taskId);
                t.liveOffers = 0;
            }
        } else if (status == TaskStatus.Closed) {
            if (
                t.requester != msg.sender && _offers[taskId][msg.sender].state == OfferState.None
                    && !umc.isAdmin(msg.sender)
            ) revert TasksNotParticipant(taskId, msg.sender);
            if (t.status != TaskStatus.Open) revert TasksNotOpen(taskId, t.status);
            if (block.timestamp <= t.deadline) revert TasksDeadlineNotPassed(taskId, t.deadline);
            counted = _settleOffers(taskId, t);
        } else {
            revert TasksBadStatus(status);
        }
        t.status = status;
        uint256 unsettled = t.numWorkers - t.settled;
        t.settled = t.numWorkers;
        if (unsettled != 0) _credit(t.requester, taskId, unsettled * _reqs[taskId].reward);
        emit TaskStatusUpdated(taskId, status);
        _count(taskId, counted); // interactions last: every state change is written
    }

    /**
     * @dev The requester gives up the slots nobody holds: offers past their acceptance window
     * expire, then every slot neither accepted nor inside a live offer is removed from the
     * task (numWorkers shrinks) and its reward refunded. Workers who accepted keep their
     * slots and rewards. With no slot left the task is Cancelled; with every remaining slot
     * reviewed it is Completed, and its offers never accepted then count as assigned (A of
     * Eq. 17; a Cancelled task counts none: nobody holds a slot).
     * Requirements: caller is the task's requester; task open; before the deadline; at least
     * one slot neither accepted nor offered. Emits {OfferExpired} per stale offer, a
     * {SlotsCancelled}, a {PaymentCredited} and possibly a {TaskStatusUpdated} event.
     */
    function cancelOpenSlots(uint256 taskId) external returns (uint256 cancelled) {
        Task storage t = _tasks[taskId];
        _checkRequester(t, taskId);
        _checkOpen(t, taskId);
        (uint256 live,) = _expireOffers(taskId, t.requester);
        cancelled = t.numWorkers - live - t.filled;
        if (cancelled == 0) revert TasksNoOpenSlot(taskId);
        uint8 left = uint8(t.numWorkers - cancelled);
        t.numWorkers = left;
        t.liveOffers = uint8(live);
        emit SlotsCancelled(taskId, uint8(cancelled), left);
        _credit(t.requester, taskId, cancelled * _reqs[taskId].reward);
        if (left == 0) {
            t.status = TaskStatus.Cancelled;
            emit TaskStatusUpdated(taskId, TaskStatus.Cancelled);
        } else if (t.settled == left) {
            // every slot left is reviewed, so held (filled == left): the unaccepted offers count
            t.status = TaskStatus.Completed;
            emit TaskStatusUpdated(taskId, TaskStatus.Completed);
            _count(taskId, _unaccepted(taskId, t)); // interactions last
        }
    }

    // ---------------------------------------------------------------------------- worker

    /**
     * @dev The offered worker accepts within the acceptance window; the offer counts as
     * assigned and accepted (A and Ac of Eq. 17) now, in one UMC update.
     * Requirements: task open; caller holds a live offer; now <= expiry.
     * Emits an {OfferAccepted} event.
     */
    function acceptOffer(uint256 taskId) external {
        Task storage t = _tasks[taskId];
        _checkOpen(t, taskId);
        Offer storage o = _offers[taskId][msg.sender];
        if (o.state != OfferState.Offered) revert TasksNotOfferedWorker(taskId, msg.sender);
        if (block.timestamp > o.expiry) revert TasksOfferExpired(taskId, msg.sender, o.expiry);
        o.state = OfferState.Accepted;
        t.liveOffers -= 1;
        t.filled += 1;
        umc.updateInfo(msg.sender, _reqs[taskId].domain, TRAINING, ASSIGNED | ACCEPTED, 0);
        emit OfferAccepted(taskId, msg.sender);
    }

    /**
     * @dev The offered worker declines; the slot goes to the next best at the next
     * {allocateTask}. No counter moves now: the offer counts as assigned at the task's end if
     * a worker holds a slot then. Requirements: caller holds a live offer on an open task.
     * Emits an {OfferDeclined} event.
     */
    function declineOffer(uint256 taskId) external {
        Task storage t = _tasks[taskId];
        if (t.status != TaskStatus.Open) revert TasksNotOpen(taskId, t.status);
        Offer storage o = _offers[taskId][msg.sender];
        if (o.state != OfferState.Offered) revert TasksNotOfferedWorker(taskId, msg.sender);
        o.state = OfferState.Declined;
        t.liveOffers -= 1;
        emit OfferDeclined(taskId, msg.sender);
    }

    /**
     * @dev An assigned worker gives the task back (its job failed: out of memory, a crash,
     * a spec it cannot train after all) instead of holding the slot until the deadline. The
     * offer becomes Failed (it stays counted as accepted and never completed, so Eq. 18
     * lowers the worker's reputation as a missed deadline would) and the slot opens again
     * (`filled` - 1: a slot given back is not held at the task's end):
     * the requester may {allocateTask} it to the next best worker (this one stays excluded)
     * or, with no other worker holding the task, cancel it and take the escrow back.
     * Given back in time, i.e. while the slot can still be offered to another worker
     * ({allocateTask}'s now + acceptWindow + minWorkTime <= deadline), it is not rated; given
     * back later, the slot was held as long as it could be of use to anyone, so it is rated 0
     * as the close rates a slot held to the deadline (otherwise a worker could hold a slot to
     * its last second and dodge that rating; docs/chain.md, "Held-out pass of 2026-12-04").
     * Requirements: task open; caller accepted the task and has not submitted.
     * Emits an {OfferFailed} event (and the UMC's {WorkerInfoUpdated} when rated).
     */
    function abandonOffer(uint256 taskId) external {
        Task storage t = _tasks[taskId];
        _checkOpen(t, taskId);
        Offer storage o = _offers[taskId][msg.sender];
        if (o.state != OfferState.Accepted) revert TasksNotAssignedWorker(taskId, msg.sender);
        o.state = OfferState.Failed;
        t.filled -= 1;
        emit OfferFailed(taskId, msg.sender);
        if (block.timestamp + acceptWindow + minWorkTime > t.deadline) {
            // interactions last: too late for another worker, rated 0 as a slot held to the end
            umc.updateInfo(msg.sender, _reqs[taskId].domain, TRAINING, REVIEWED, 0);
        }
    }

    /**
     * @dev An assigned worker submits the outcome's IPFS CID before the deadline. It counts
     * as a completed task (E of Eq. 18, N of Eq. 16) only once accepted ({reviewOutcome}) or
     * paid at close unreviewed: a rejected outcome is not a completed task. The CID is
     * recorded as this worker's outcome of this task ({outcomeOf}); a CID is an outcome once on this chain,
     * so no worker can hand in a model already submitted (by itself or anyone else) for
     * another task or slot, nor one already listed on the MMC ({setModels}): a shared model
     * handed in as an outcome would be someone else's work, and its outcome record would
     * name the wrong producer of a listed model.
     * Requirements: task open; caller accepted the task and has not submitted; before the
     * deadline; non-empty CID in {CidText}'s form (lowercase base32 CIDv1), never submitted before nor listed as a model; the caller
     * committed {cidCommitment}(cid, caller) in an earlier block ({commitCid}; the commitment
     * is spent). Emits an {OutcomeSubmitted} event.
     */
    function submitOutcome(uint256 taskId, string calldata cid) external {
        Task storage t = _tasks[taskId];
        _checkOpen(t, taskId);
        Offer storage o = _offers[taskId][msg.sender];
        if (o.state != OfferState.Accepted) revert TasksNotAssignedWorker(taskId, msg.sender);
        if (bytes(cid).length == 0) revert TasksEmptyCid();
        if (!CidText.isCanonical(cid)) revert TasksCidNotCanonical(cid);
        OutcomeRecord storage rec = _outcomes[keccak256(bytes(cid))];
        if (rec.worker != address(0)) revert TasksDuplicateOutcome(rec.taskId, rec.worker);
        if (address(models) != address(0)) {
            uint256 listed = models.modelOfCid(keccak256(bytes(cid)));
            if (listed != 0) revert TasksOutcomeIsListedModel(listed);
        }
        bytes32 commitment = cidCommitment(cid, msg.sender);
        if (!_committedBefore(commitment)) revert TasksCidNotCommitted(commitment);
        delete _commits[commitment]; // its ring slot keeps the hash until overwritten: harmless
        (rec.worker, rec.taskId) = (msg.sender, uint64(taskId));
        o.state = OfferState.Submitted;
        emit OutcomeSubmitted(taskId, msg.sender, cid);
    }

    /**
     * @dev A worker commits to a CID it will reveal later ({submitOutcome}, MMC addModel),
     * before anyone can read the CID; `commitment` is {cidCommitment}(cid, caller), which
     * hides the CID and binds it to the caller (a copied commitment reveals nothing for the
     * copier). Committing the same commitment again keeps the first block and emits nothing,
     * so a worker that retries after a crash loses no priority.
     * Requirements: caller is an approved worker (Active or Idle), or a worker that accepted
     * a training task here at some point (a worker sent back to Pending by a change of
     * capabilities, or removed, may still hold an accepted job and must be able to submit
     * it); otherwise {TasksNotWorker}. A stranger's registration (Pending, never approved,
     * never offered anything) does not let it write commitment slots.
     * Bounded: a worker's commitments live in a ring of MAX_LIVE_COMMITMENTS; its new
     * commitment takes the ring's oldest position and evicts the commitment there if that one
     * is still unspent and was committed by this worker at that position (a commitment another
     * worker committed first is that worker's to evict, never this one's). So a worker's
     * commitments hold at most MAX_LIVE_COMMITMENTS record slots, and a live commitment is
     * evicted only by 16 newer commitments of its own committer (the daemon reveals each
     * within one upload; docs/chain.md, "Held-out pass of 2026-12-05, second").
     * Emits a {CidCommitted} event, and a {CidCommitmentEvicted} event when one is evicted.
     */
    function commitCid(bytes32 commitment) external {
        (uint32 id, uint256 word) = umc.workerRecord(msg.sender);
        uint256 status = word.status();
        if (id == 0 || (status != Packed.ACTIVE && status != Packed.IDLE && !_acceptedBefore(id, word))) {
            revert TasksNotWorker(msg.sender);
        }
        if (_commits[commitment] != 0) return;
        uint256 made = _commitsMade[id];
        uint256 pos = made % MAX_LIVE_COMMITMENTS;
        if (made >= MAX_LIVE_COMMITMENTS) {
            bytes32 oldest = _commitRing[id][pos];
            uint256 rec = _commits[oldest];
            // still live, this worker's, and recorded at this position (not spent and made again since)
            if (rec != 0 && uint32(rec >> 64) == id && uint8(rec >> 96) == pos) {
                delete _commits[oldest];
                emit CidCommitmentEvicted(msg.sender, oldest);
            }
        }
        _commitRing[id][pos] = commitment;
        _commitsMade[id] = made + 1;
        // block.number < 2^64, id < 2^32, pos < 16: the fields do not overlap
        _commits[commitment] = block.number | (uint256(id) << 64) | (pos << 96);
        emit CidCommitted(msg.sender, commitment);
    }

    /// @dev Block in which `commitment` was committed ({commitCid}); 0 if never, or once
    /// spent ({submitOutcome}) or evicted (a newer commitment of its committer's ring).
    function cidCommits(bytes32 commitment) external view returns (uint256) {
        return uint64(_commits[commitment]);
    }

    /// @dev What {commitCid} takes for `cid` revealed by `worker`: keccak256(cid ++ worker).
    function cidCommitment(string calldata cid, address worker) public pure returns (bytes32) {
        return keccak256(abi.encodePacked(cid, worker));
    }

    /// @inheritdoc ITasksOutcomes
    function committedBefore(bytes32 commitment) external view returns (bool) {
        return _committedBefore(commitment);
    }

    /// @inheritdoc ITasksOutcomes
    function taskDomain(uint256 taskId) external view returns (uint32) {
        return _reqs[taskId].domain;
    }

    function _committedBefore(bytes32 commitment) internal view returns (bool) {
        uint256 committedAt = uint64(_commits[commitment]);
        return committedAt != 0 && committedAt < block.number;
    }

    // ---------------------------------------------------------------------------- payments

    /**
     * @dev Sends the caller's credited balance (pull payment; CEI plus reentrancy guard).
     * Requirements: a positive credit. Emits a {Withdrawn} event.
     */
    function withdraw() external nonReentrant {
        uint256 amount = credits[msg.sender];
        if (amount == 0) revert TasksNothingToWithdraw(msg.sender);
        credits[msg.sender] = 0;
        emit Withdrawn(msg.sender, amount);
        (bool ok,) = msg.sender.call{value: amount}("");
        if (!ok) revert TasksTransferFailed(msg.sender, amount);
    }

    // ---------------------------------------------------------------------------- views

    function getTask(uint256 taskId) external view returns (Task memory, Reqs memory) {
        return (_tasks[taskId], _reqs[taskId]);
    }

    function getOffer(uint256 taskId, address worker) external view returns (Offer memory) {
        return _offers[taskId][worker];
    }

    function offerees(uint256 taskId) external view returns (address[] memory) {
        return _offerees[taskId];
    }

    /// @dev Every task ever posted in `domain`, in posting order (thesis Domain Tasks). Its
    /// gas grows with the domain's tasks, so past some thousands an eth_call runs out of gas:
    /// read {domainTasksPage} instead (kept for small domains and existing callers).
    function domainTasks(uint32 domain) external view returns (uint256[] memory) {
        return _domainTasks[domain];
    }

    /**
     * @dev The tasks of `domain` at positions [offset, offset + count) of its posting order
     * (as {UsersManager.getWorkers} pages workers) and how many it has in all: the page is
     * shorter at the end and empty past it, and its gas is bounded by `count`.
     */
    function domainTasksPage(uint32 domain, uint256 offset, uint256 count)
        external
        view
        returns (uint256[] memory page, uint256 total)
    {
        uint256[] storage list = _domainTasks[domain];
        total = list.length;
        uint256 n = offset < total ? total - offset : 0;
        if (n > count) n = count;
        page = new uint256[](n);
        for (uint256 i; i < n; ++i) {
            page[i] = list[offset + i]; // offset + i < total
        }
    }

    /// @inheritdoc ITasksOutcomes
    function outcomeOf(bytes32 cidHash) external view returns (address worker, uint256 taskId, Verdict verdict) {
        OutcomeRecord memory rec = _outcomes[cidHash];
        if (rec.worker == address(0)) return (address(0), 0, Verdict.None);
        Offer storage o = _offers[rec.taskId][rec.worker];
        if (o.state == OfferState.Submitted) verdict = Verdict.Pending;
        else verdict = o.paid ? Verdict.Accepted : Verdict.Rejected;
        return (rec.worker, rec.taskId, verdict);
    }

    /// @dev Least reward per worker for a task of `duration` seconds:
    /// ceil(minRewardPerHour * duration / 3600) wei, and at least 1 wei (no free tasks).
    function minRewardForDuration(uint256 duration) public view returns (uint256) {
        uint256 minimum = (minRewardPerHour * duration + 3599) / 3600;
        return minimum == 0 ? 1 : minimum;
    }

    // ---------------------------------------------------------------------------- internal

    /**
     * @dev Eq. 16-21 over the candidates, then greedy top-k. Pass 1 applies the constraints
     * of 7.5.1 and keeps Rep*R*CC (exact product, < 1e18) and E per eligible worker, and
     * N_max over all eligible workers (skipped ones included, as qos.py); pass 2 forms
     * QoS = floor(Exp * Rep * R * CC / 1e18) and keeps the k best by the key QoS << 32 |
     * (2^32 - 1 - worker id): ties go to the lower worker id whatever the pool order. The
     * returned `qs` are keys (QoS = key >> 32).
     */
    function _select(Reqs memory r, uint256[] memory ws, uint256[] memory cs, address[] memory skip, uint256 k)
        internal
        view
        returns (uint256[] memory idx, uint256[] memory qs, uint256 count)
    {
        uint256 n = ws.length;
        uint256[] memory part = new uint256[](n);
        uint256 nMax = 0;
        uint256 gpus = acceptedGpus;
        uint256 weight = w1;
        for (uint256 i; i < n; ++i) {
            uint256 w = ws[i];
            if (
                w.status() != Packed.ACTIVE || w.cores() < r.minCpuCores || w.ram() < r.minRamGb
                    || (gpus >> w.gpu()) & 1 == 0
            ) continue;
            uint256 c = cs[i];
            uint256 rep = QoSMath.reputation(c.assigned(), c.accepted(), c.completed());
            if (rep < r.minReputation) continue;
            uint256 rat = QoSMath.rating(c.ratingSum(), c.ratingCount());
            if (rat < r.minRating) continue;
            uint256 e = c.completed();
            if (e > nMax) nMax = e;
            part[i] = ELIGIBLE | (e << 64) | (rep * rat * QoSMath.atanFixed(weight * w.cores()));
        }
        idx = new uint256[](k);
        qs = new uint256[](k);
        for (uint256 i; i < n; ++i) {
            uint256 p = part[i];
            if (p == 0 || _contains(skip, ws[i].addr())) continue;
            uint256 q = (QoSMath.expertise(uint48(p >> 64), nMax) * uint64(p)) / 1e18;
            count = QoSMath.insertTop(idx, qs, count, i, (q << 32) | (ID_MASK - ws[i].id()));
        }
    }

    function _contains(address[] memory list, address a) internal pure returns (bool) {
        for (uint256 j; j < list.length; ++j) {
            if (list[j] == a) return true;
        }
        return false;
    }

    /// @dev Marks offers past their window Expired and returns the number of live offers and
    /// the addresses to skip: every offeree (the "next best" rule) and, no self-dealing, the
    /// requester (a requester who is also a worker could otherwise review itself up).
    /// Skipped workers still count for N_max. Bounded by MAX_OFFERS.
    function _expireOffers(uint256 taskId, address requester)
        internal
        returns (uint256 live, address[] memory skip)
    {
        address[] storage list = _offerees[taskId];
        uint256 m = list.length;
        skip = new address[](m + 1);
        skip[m] = requester;
        for (uint256 j; j < m; ++j) {
            address a = list[j];
            skip[j] = a;
            Offer storage o = _offers[taskId][a];
            if (o.state != OfferState.Offered) continue;
            if (block.timestamp > o.expiry) {
                o.state = OfferState.Expired;
                emit OfferExpired(taskId, a);
            } else {
                ++live;
            }
        }
    }

    /// @dev At close: pay unreviewed outcomes (after the review window; they count as
    /// completed), fail the accepted offers without outcome (rated 0: holding a slot to the
    /// deadline costs more than declining or an {abandonOffer} in time), expire the rest; the offers
    /// never accepted count as assigned if a worker held a slot at the deadline
    /// (`filled` != 0). Returns the UMC flags per offeree for {_count} (state only here).
    /// Bounded by MAX_OFFERS.
    function _settleOffers(uint256 taskId, Task storage t) internal returns (uint8[] memory counted) {
        address[] storage list = _offerees[taskId];
        uint256 m = list.length;
        counted = new uint8[](m);
        uint8 missed = t.filled != 0 ? ASSIGNED : 0;
        Reqs storage r = _reqs[taskId];
        uint256 reward = r.reward;
        uint256 reviewEnd = r.reviewEnd;
        for (uint256 j; j < m; ++j) {
            address a = list[j];
            Offer storage o = _offers[taskId][a];
            OfferState s = o.state;
            if (s == OfferState.Submitted) {
                if (block.timestamp <= reviewEnd) revert TasksReviewWindowOpen(taskId, reviewEnd);
                o.state = OfferState.Reviewed;
                o.paid = true;
                t.settled += 1;
                _credit(a, taskId, reward);
                counted[j] = COMPLETED;
                emit OutcomePaidUnreviewed(taskId, a);
            } else if (s == OfferState.Accepted) {
                o.state = OfferState.Failed;
                counted[j] = REVIEWED; // with review 0
                emit OfferFailed(taskId, a);
            } else if (s == OfferState.Offered) {
                o.state = OfferState.Expired;
                counted[j] = missed;
                emit OfferExpired(taskId, a);
            } else if (s == OfferState.Declined || s == OfferState.Expired) {
                counted[j] = missed;
            }
        }
        t.liveOffers = 0;
    }

    /// @dev The end of a task some worker held a slot of (completed by its last review or by
    /// {cancelOpenSlots}): ASSIGNED for each offer never accepted (declined or expired), the
    /// UMC flags per offeree for {_count}. The offeree lost a task that found workers, which is
    /// what Eq. 17 measures; a task that ends with no slot held counts none of these
    /// (docs/chain.md, "Offers that count"). Bounded by MAX_OFFERS.
    function _unaccepted(uint256 taskId, Task storage t) internal view returns (uint8[] memory counted) {
        address[] storage list = _offerees[taskId];
        uint256 m = list.length;
        counted = new uint8[](m);
        if (t.filled == 0) return counted;
        for (uint256 j; j < m; ++j) {
            OfferState s = _offers[taskId][list[j]].state;
            if (s == OfferState.Declined || s == OfferState.Expired) counted[j] = ASSIGNED;
        }
    }

    /// @dev Whether worker `id` (UMC word `word`) accepted a training task in one of its
    /// domains (Ac > 0): only an approved worker is ever offered one. At most
    /// UMC.MAX_WORKER_DOMAINS (4) calls; only for callers neither Active nor Idle.
    function _acceptedBefore(uint32 id, uint256 word) internal view returns (bool) {
        uint32[] memory ids = new uint32[](1);
        ids[0] = id;
        uint256 domains = uint48(word >> 208);
        for (uint32 d; domains != 0; ++d) {
            if (domains & 1 == 1) {
                // only the counters are needed: the worker word came with {IUsersManager.workerRecord}
                // slither-disable-next-line unused-return
                (, uint256[] memory stats) = umc.profiles(ids, d, TRAINING);
                if (stats[0].accepted() != 0) return true;
            }
            domains >>= 1;
        }
        return false;
    }

    /// @dev Moves the UMC counters of the task's offerees by `counted` (0: none), after the
    /// caller wrote every state change (the UMC is the platform registry set at
    /// construction and makes no external call). Bounded by MAX_OFFERS.
    function _count(uint256 taskId, uint8[] memory counted) internal {
        address[] storage list = _offerees[taskId];
        uint32 domain = _reqs[taskId].domain;
        for (uint256 j; j < counted.length; ++j) {
            uint8 flags = counted[j];
            if (flags != 0) umc.updateInfo(list[j], domain, TRAINING, flags, 0);
        }
    }

    function _credit(address account, uint256 taskId, uint256 amount) internal {
        // A zero credit is skipped, not a balance test: slither's taint from block.timestamp
        // reaches `amount` only through the task's Reqs word, whose reviewEnd is a time.
        // slither-disable-next-line incorrect-equality
        if (amount == 0) return;
        credits[account] += amount;
        emit PaymentCredited(account, taskId, amount);
    }

    function _setConfig(uint64 w1_, uint32 acceptWindow_, uint32 reviewWindow_) internal {
        if (w1_ == 0 || w1_ > 1e12 || acceptWindow_ == 0 || reviewWindow_ == 0 || reviewWindow_ > MAX_REVIEW_WINDOW) {
            revert TasksBadConfig();
        }
        _checkLimits(acceptWindow_, minWorkTime, maxDuration);
        (w1, acceptWindow, reviewWindow) = (w1_, acceptWindow_, reviewWindow_);
        emit ConfigUpdated(w1_, acceptWindow_, reviewWindow_);
    }

    /// @dev A task must be able to last acceptWindow + minWorkTime within maxDuration.
    function _checkLimits(uint256 acceptWindow_, uint256 minWorkTime_, uint256 maxDuration_) internal pure {
        if (minWorkTime_ == 0 || maxDuration_ > type(uint32).max || acceptWindow_ + minWorkTime_ > maxDuration_) {
            revert TasksBadConfig();
        }
    }

    function _checkAdmin() internal view {
        if (!umc.isAdmin(msg.sender)) revert TasksNotAdmin(msg.sender);
    }

    function _checkRequester(Task storage t, uint256 taskId) internal view {
        if (t.status == TaskStatus.None) revert TasksUnknownTask(taskId);
        if (t.requester != msg.sender) revert TasksNotTaskRequester(taskId, msg.sender);
    }

    function _checkOpen(Task storage t, uint256 taskId) internal view {
        if (t.status != TaskStatus.Open) revert TasksNotOpen(taskId, t.status);
        if (block.timestamp > t.deadline) revert TasksDeadlinePassed(taskId, t.deadline);
    }
}
