// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

import {ReentrancyGuardTransient} from "@openzeppelin/contracts/utils/ReentrancyGuardTransient.sol";
import {IUsersManager, Packed} from "./IUsersManager.sol";
import {ITasksOutcomes} from "./ITasksOutcomes.sol";
import {QoSMath} from "./QoSMath.sol";
import {CidText} from "./CidText.sol";

/**
 * @title ModelsManager (MMC, thesis Tables 5.2 and 7.4)
 * @dev Shared DRL models (IPFS CID, domain, environment details) and their allocation to
 * requesters by greedy top-N QoS, with either metric:
 *  - Metric.Model   (thesis 5.3.1): QoS_m = Rep_i * Rep_m / (1 + D_m), Eq. 10-13;
 *  - Metric.Sharing (thesis 7.5.2): QoS = Exp * Rep_MS * R_MS / (1 + S), Eq. 16-19, 22-23,
 *    with the owner's model-sharing counters kept by the UMC.
 * The requester pays the same price per requested model (5.3.1); each allocated model's
 * price is credited to its owner at allocation (the model is already published, so the
 * share is immediate), unfilled slots are refunded, and the requester reviews each
 * allocated model once ({updateModelRep}), which updates Eq. 10, Eq. 11 and the owner's
 * model-sharing rating. Counters (A, Ac, E of Eq. 17-18) grow by one per allocation.
 *
 * The requester's own models are never allocated to it (no self-review).
 *
 * Paid allocations only: every allocation counts in Eq. 10 and Eq. 11 (its model is judged
 * by it, reviewed or not, as in the thesis), so a free allocation would let anyone drive any
 * model's and owner's reputation to 0. The price per model must be at least
 * {minModelPrice} (admin-set, never below 1 wei); every allocation that counts against a
 * model pays its owner (docs/chain.md, "Paid model allocations").
 *
 * One model, one slot: a model id appears at most once in an allocation (the greedy top-N
 * runs over the domain's list, where each model is once) and a CID is listed once, so one
 * upload is never sold twice in one allocation. Byte-different copies of the same weights
 * under another CID are not detectable on chain (docs/chain.md, "Duplicate models").
 *
 * Eq. 12 uses 1 + D_m (smoothing, as Eq. 23), which can reorder models against the thesis's
 * Rep_i * Rep_m / D_m when D_m > 0; the decided ranking (exact matches first, then
 * Rep_i * Rep_m / D_m) is documented in docs/chain.md and not applied yet.
 *
 * Public models: a listed model is public ({getModel}, {ModelAdded}, its files in the store);
 * prices pay for allocation and ranking, not for secrecy. A task outcome sealed to its
 * requester is listed only once its owner publishes the files (docs/chain.md, "Outcomes are
 * public before payment").
 * Candidates (issue 8, allocation that scales): only the models of the owners in the
 * domain's UMC candidate pool (at most UMC.MAX_POOL_SIZE approved Active workers) are
 * considered, and an owner lists at most {maxModelsPerOwner} models (admin setting, at most
 * MAX_MODELS_PER_OWNER) in the domains it covers, so {allocateModel} reads at most
 * MAX_POOL_SIZE * MAX_MODELS_PER_OWNER models whatever the number of models listed. Equal
 * QoS goes to the lower model id. backend/chain/qos.py applies the same rule (`pool`
 * arguments); docs/chain.md, "Candidate pools".
 *
 * Provenance (thesis 7.7): a CID is listed once. A CID that is a training outcome on the
 * TMC may be shared only by the worker who submitted it, and only once its requester
 * accepted it (or it was paid unreviewed at close): while the review is pending the model
 * is the requester's to judge, and a rejected outcome stays unlisted, since the requester's
 * review is the only quality evidence the chain holds for it. It is listed in its task's
 * domain only: that acceptance vouches for the domain the task was posted in, not for
 * another domain its worker also covers (docs/chain.md, "Held-out pass of 2026-12-05").
 * A CID that is no outcome is an owner's own upload; the gateway checks that its card
 * matches the declared environment.
 *
 * Gas: a model is one slot in its owner's list of the domain: model id, attribute count,
 * both Eq. 11 totals and its first four environment attributes (uint32 each), the list's
 * length in the first one, so a candidate with d <= 4 attributes costs one cold SLOAD and
 * an owner nothing more; attributes 5-12 go eight per slot. The
 * CID is stored (requesters read it after allocation); the description lives only in the
 * {ModelAdded} event.
 */
contract ModelsManager is ReentrancyGuardTransient {
    using Packed for uint256;

    uint8 internal constant SHARING = 1;
    uint8 internal constant SHARED = 1 | 2 | 4; // ASSIGNED | ACCEPTED | COMPLETED
    uint8 internal constant REVIEWED = 8;
    uint256 public constant MAX_MODELS = 16;
    /// Attributes of a model's environment: 4 in the model word and 8 in one more word, so an
    /// allocation reads at most two words per model (64 attributes made it 9: at the largest
    /// pool and owner limits an allocation then needed ~95M gas; the platform's EnvSpec has 6).
    uint256 public constant MAX_ENV_DIMS = 12;
    /// Upper bound of {maxModelsPerOwner}.
    uint256 public constant MAX_MODELS_PER_OWNER = 16;
    uint32 public constant DEFAULT_MODELS_PER_OWNER = 8;
    uint256 internal constant ID_MASK = (1 << 32) - 1;
    uint256 internal constant ONE = QoSMath.ONE;
    uint256 internal constant MODELS_PER_WORD = 7;
    uint256 internal constant REVIEWED_SHIFT = 224;
    /// Longest model description {addModel} takes (bytes): the gateway takes at most 1,024
    /// characters, at most 4 bytes each in UTF-8 (docs/chain.md, "Held-out pass of
    /// 2026-12-05, second"); the TMC's task descriptions have the same cap.
    uint256 public constant MAX_DESCRIPTION_BYTES = 4096;

    enum Metric {
        Model, // Eq. 10-13
        Sharing // Eq. 22-23
    }

    enum AllocState {
        None,
        Allocated,
        Reviewed
    }

    /// A model, stored in its owner's list of the domain (position j of key ownerId << 8 |
    /// domain): the owner and the domain are the key, so the word holds the model id and, in
    /// the list's first record, how many models the list has. An allocation scan reads one
    /// cold slot per model and nothing else per owner (docs/chain.md, "Gas against Table 7.5").
    struct Model {
        uint32 modelId;
        uint8 listLength; // record 0 only: models of this owner in this domain (<= 16)
        uint8 envLen;
        uint40 allocCount; // Eq. 11 denominator
        uint40 totalReview; // Eq. 11 numerator (reviews in [0, 5])
        uint128 envHead; // attributes 0-3, attribute j at bits 32j
    }

    /// What {getModel} returns (owner resolved to its address).
    struct ModelView {
        address owner;
        uint8 domain;
        uint8 envLen;
        uint40 allocCount;
        uint40 totalReview;
    }

    struct OwnerRep {
        uint40 allocCount; // Eq. 10: allocations of all the owner's models
        uint40 totalReview;
    }

    /// Per owner (UMC worker id), one slot: the Eq. 10 totals, the number of models it
    /// listed (all domains) and what its allocated models earned and it has not withdrawn
    /// (wei; < 2^40 allocations x 2^80 wei per model < 2^144). The owner's first allocation
    /// rewrites the slot its first listing created instead of creating one, and paying the
    /// owner is part of that rewrite: no credit slot of its own (docs/chain.md, "Gas against
    /// Table 7.5").
    struct OwnerRecord {
        uint40 allocCount;
        uint40 totalReview;
        uint32 modelCount;
        uint144 credit;
    }

    struct Allocation {
        address requester;
        uint8 domain;
        Metric metric;
        uint80 price;
    }

    struct ModelRequest {
        uint32 domain;
        uint8 numModels;
        Metric metric;
        uint32 minReputation; // Model: owner Rep_i (Eq. 10); Sharing: Rep_MS (Eq. 19)
        uint32 minRating; // Sharing only: R_MS
        uint32 minModelReputation; // Model only: Rep_m (Eq. 11)
        uint32[] env; // requester's environment attributes (E^r / F^T)
        uint32[] weights; // Eq. 13/22 weights scaled by 1e6 summing to 1e6; empty = equal
    }

    /// What the candidate scans of {allocateModel} read from the request, read once.
    struct Scan {
        uint256 domain;
        uint256 minA; // Model: Rep_i (Eq. 10); Sharing: Rep_MS (Eq. 19)
        uint256 minB; // Model: Rep_m (Eq. 11); Sharing: R_MS
        uint256 selfId; // the requester's worker id (0 if none): its models are skipped
        uint256[] env;
        uint256[] weights;
    }

    error ModelsNotWorker(address account);
    error ModelsNotApproved(address account);
    error ModelsOwnerNotInDomain(address account, uint32 domain);
    error ModelsOwnerLimit(address account, uint256 limit);
    error ModelsNotAdmin(address account);
    error ModelsBadLimit(uint256 limit);
    error ModelsNotRequester(address account);
    error ModelsBadDomain(uint32 domain);
    error ModelsEmptyCid();
    error ModelsDescriptionTooLong(uint256 length, uint256 maximum);
    /// The CID is not in the one text form the chain records (lowercase base32 CIDv1).
    error ModelsCidNotCanonical(string cid);
    error ModelsBadEnv(uint256 length);
    error ModelsBadModelCount(uint8 numModels);
    error ModelsBadWeights();
    error ModelsBadThreshold(uint32 value);
    error ModelsBadPayment(uint256 value, uint8 numModels);
    error ModelsNoEligibleModel(uint32 domain);
    error ModelsNotAllocationRequester(uint256 allocId, address account);
    error ModelsNotAllocated(uint256 allocId, uint256 modelId);
    error ModelsBadReview(uint8 review);
    error ModelsNothingToWithdraw(address account);
    error ModelsTransferFailed(address account, uint256 amount);
    error ModelsNotOutcomeOwner(uint256 taskId, address worker);
    error ModelsOutcomeNotAccepted(uint256 taskId, ITasksOutcomes.Verdict verdict);
    /// An outcome is listed in the domain of its task, not in another the worker covers.
    error ModelsOutcomeDomainMismatch(uint256 taskId, uint32 taskDomain, uint32 domain);
    error ModelsDuplicateModel(uint256 modelId);
    error ModelsCidNotCommitted(bytes32 commitment);
    error ModelsBadConfig();
    error ModelsPriceBelowMinimum(uint256 price, uint256 minimum);

    event ModelAdded(
        uint256 indexed modelId,
        address indexed owner,
        uint32 indexed domain,
        string cid,
        string description,
        uint32[] env
    );
    event ModelsRequested(
        uint256 indexed allocId,
        address indexed requester,
        uint32 indexed domain,
        Metric metric,
        uint8 numModels,
        uint80 price
    );
    event ModelAllocated(uint256 indexed allocId, uint256 indexed modelId, address indexed owner, uint256 qos);
    event ModelReviewed(uint256 indexed allocId, uint256 indexed modelId, uint8 review);
    event PaymentCredited(address indexed account, uint256 indexed allocId, uint256 amount);
    event Withdrawn(address indexed account, uint256 amount);
    event MinModelPriceUpdated(uint256 weiPerModel);
    event MaxModelsPerOwnerUpdated(uint256 limit);

    IUsersManager public immutable umc;
    /// The TMC whose outcomes the provenance rule checks.
    ITasksOutcomes public immutable tmc;
    /// Counters and settings in one slot: {modelCount}, {allocCount}, {minModelPrice} (least
    /// price per allocated model, wei, >= 1: allocations count in Eq. 10-11) and
    /// {maxModelsPerOwner} (models one owner may list, all domains together; admin settings).
    /// The constructor writes the slot, so the first listing and the first allocation rewrite
    /// it instead of creating a slot, and an allocation reads its price floor and id counter
    /// in one SLOAD. Ids stay below 2^32 in practice (models are listed as uint32).
    struct Globals {
        uint64 modelCount;
        uint64 allocCount;
        uint80 minModelPrice; // <= type(uint80).max (setMinModelPrice)
        uint32 maxModelsPerOwner;
    }

    Globals internal _g;

    /// Models by owner list (key = owner id << 8 | domain) and position in it, in listing
    /// order: one slot per model, record 0 also holding the list's length.
    mapping(uint256 => mapping(uint256 => Model)) internal _models;
    /// Where model `id` is: its owner list key << 8 | its position in that list (0 = none).
    mapping(uint256 => uint256) internal _modelAt;
    /// Attributes 4.. of a model, eight uint32 per word: word k holds attributes 4+8k..11+8k.
    mapping(uint256 => mapping(uint256 => uint256)) internal _envTail;
    mapping(uint256 => string) internal _cids;
    /// Domain Models (thesis: uint -> Model[]), as model ids in submission order.
    mapping(uint256 => uint32[]) internal _domainModels;
    mapping(uint32 => OwnerRecord) internal _owners; // by UMC worker id
    mapping(uint256 => Allocation) internal _allocs;
    /// Models of an allocation, MODELS_PER_WORD per word (word k holds entries 7k..7k+6):
    /// entry e's model id at bits 32e, its reviewed flag at bit REVIEWED_SHIFT + e; an
    /// allocation of up to 7 models is one storage slot instead of one per model.
    mapping(uint256 => mapping(uint256 => uint256)) internal _allocModels;
    /// Withdrawable balances other than model earnings (refunds of unfilled slots), by
    /// address; an owner's earnings are in its {OwnerRecord}. {credits} sums the two.
    mapping(address => uint256) internal _credits;
    /// keccak256(cid) -> the model listing it (0 = not listed).
    mapping(bytes32 => uint256) public modelOfCid;

    constructor(IUsersManager umc_, ITasksOutcomes tmc_) {
        umc = umc_;
        tmc = tmc_;
        _g.minModelPrice = 1;
        emit MinModelPriceUpdated(1);
        _g.maxModelsPerOwner = DEFAULT_MODELS_PER_OWNER;
        emit MaxModelsPerOwnerUpdated(DEFAULT_MODELS_PER_OWNER);
    }

    /**
     * @dev Sets the least price per allocated model (wei) that {allocateModel} accepts.
     * Requirements: caller is a consortium admin; 1 <= weiPerModel < 2^80 (prices are
     * uint80). Emits a {MinModelPriceUpdated} event.
     */
    function setMinModelPrice(uint256 weiPerModel) external {
        if (!umc.isAdmin(msg.sender)) revert ModelsNotAdmin(msg.sender);
        if (weiPerModel == 0 || weiPerModel > type(uint80).max) revert ModelsBadConfig();
        _g.minModelPrice = uint80(weiPerModel); // <= type(uint80).max, checked above
        emit MinModelPriceUpdated(weiPerModel);
    }

    /**
     * @dev Sets how many models one owner may list (all domains together); owners already
     * above a lowered limit keep their models but list no more.
     * Requirements: caller is a consortium admin; 1 <= limit <= MAX_MODELS_PER_OWNER.
     * Emits a {MaxModelsPerOwnerUpdated} event.
     */
    function setMaxModelsPerOwner(uint256 limit) external {
        if (!umc.isAdmin(msg.sender)) revert ModelsNotAdmin(msg.sender);
        if (limit == 0 || limit > MAX_MODELS_PER_OWNER) revert ModelsBadLimit(limit);
        _g.maxModelsPerOwner = uint32(limit);
        emit MaxModelsPerOwnerUpdated(limit);
    }

    /**
     * @dev A worker shares a model: IPFS `cid`, textual `description`, `domain` code and
     * environment attributes `env` (Table 5.2).
     * Requirements: caller is an approved worker (Active or Idle: not Pending, not removed)
     * covering `domain` (<= 47) and listing fewer than {maxModelsPerOwner} models; non-empty
     * CID in {CidText}'s form (lowercase base32 CIDv1) not listed before; a description of at
     * most {MAX_DESCRIPTION_BYTES} bytes; at most 12 attributes; if the CID is a TMC outcome, the caller
     * submitted it, its verdict is Accepted and `domain` is its task's domain (see the
     * contract's provenance rule), else the
     * caller committed keccak256(cid ++ caller) on the TMC in an earlier block (commitCid:
     * commit-reveal, so nobody who saw the CID pending can list it first).
     * Emits a {ModelAdded} event.
     */
    function addModel(string calldata cid, string calldata description, uint32 domain, uint32[] calldata env)
        external
        returns (uint256 modelId)
    {
        (uint32 ownerId, uint256 record) = umc.workerRecord(msg.sender);
        if (ownerId == 0) revert ModelsNotWorker(msg.sender);
        uint256 status = record.status();
        if (status != Packed.ACTIVE && status != Packed.IDLE) revert ModelsNotApproved(msg.sender);
        if (domain > Packed.MAX_DOMAIN) revert ModelsBadDomain(domain);
        if (!record.covers(domain)) revert ModelsOwnerNotInDomain(msg.sender, domain);
        uint256 owned = _owners[ownerId].modelCount;
        uint256 maxOwned = _g.maxModelsPerOwner;
        if (owned >= maxOwned) revert ModelsOwnerLimit(msg.sender, maxOwned);
        if (bytes(cid).length == 0) revert ModelsEmptyCid();
        if (!CidText.isCanonical(cid)) revert ModelsCidNotCanonical(cid);
        if (bytes(description).length > MAX_DESCRIPTION_BYTES) {
            revert ModelsDescriptionTooLong(bytes(description).length, MAX_DESCRIPTION_BYTES);
        }
        if (env.length > MAX_ENV_DIMS) revert ModelsBadEnv(env.length);
        bytes32 cidHash = keccak256(bytes(cid));
        uint256 listed = modelOfCid[cidHash];
        if (listed != 0) revert ModelsDuplicateModel(listed);
        (address worker, uint256 taskId, ITasksOutcomes.Verdict verdict) = tmc.outcomeOf(cidHash);
        if (worker != address(0)) {
            if (worker != msg.sender) revert ModelsNotOutcomeOwner(taskId, worker);
            if (verdict != ITasksOutcomes.Verdict.Accepted) revert ModelsOutcomeNotAccepted(taskId, verdict);
            // the outcome's acceptance vouches for its task's domain only (held-out pass of 2026-12-05)
            uint32 trained = tmc.taskDomain(taskId);
            if (trained != domain) revert ModelsOutcomeDomainMismatch(taskId, trained, domain);
        } else {
            bytes32 commitment = keccak256(abi.encodePacked(cid, msg.sender));
            if (!tmc.committedBefore(commitment)) revert ModelsCidNotCommitted(commitment);
        }
        modelId = ++_g.modelCount;
        modelOfCid[cidHash] = modelId;
        _owners[ownerId].modelCount = uint32(owned + 1); // owned < maxModelsPerOwner <= 16
        uint256 head = 0;
        uint256 word = 0;
        for (uint256 j; j < env.length; ++j) {
            if (j < 4) {
                head |= uint256(env[j]) << (32 * j);
                continue;
            }
            word |= uint256(env[j]) << (32 * ((j - 4) & 7));
            if ((j - 4) & 7 == 7 || j + 1 == env.length) {
                _envTail[modelId][(j - 4) >> 3] = word;
                word = 0;
            }
        }
        _listModel(ownerId, domain, modelId, env.length, head);
        _cids[modelId] = cid;
        _domainModels[domain].push(uint32(modelId));
        emit ModelAdded(modelId, msg.sender, domain, cid, description, env);
    }

    /**
     * @dev Allocates up to `numModels` models of `domain` with the highest QoS (greedy,
     * ties to the lower model id) among the models of the domain's UMC candidate pool
     * owners, and pays their owners `msg.value / numModels` each;
     * unfilled slots are refunded to the requester's credit.
     * Requirements: caller is a registered requester; 1 <= numModels <= 16; domain <= 47;
     * thresholds <= 1e6; <= MAX_ENV_DIMS (12) attributes; weights empty or one per attribute summing to 1e6;
     * msg.value a multiple of numModels; price per model (msg.value / numModels) at least
     * {minModelPrice}; at least one eligible model.
     * Emits {ModelsRequested}, one {ModelAllocated} and {PaymentCredited} per model.
     */
    function allocateModel(ModelRequest calldata r) external payable returns (uint256 allocId) {
        if (!umc.isRequester(msg.sender)) revert ModelsNotRequester(msg.sender);
        if (r.numModels == 0 || r.numModels > MAX_MODELS) revert ModelsBadModelCount(r.numModels);
        if (r.domain > Packed.MAX_DOMAIN) revert ModelsBadDomain(r.domain);
        if (r.minReputation > ONE) revert ModelsBadThreshold(r.minReputation);
        if (r.minRating > ONE) revert ModelsBadThreshold(r.minRating);
        if (r.minModelReputation > ONE) revert ModelsBadThreshold(r.minModelReputation);
        // Exact division, checked right below (price * N == msg.value): nothing is lost.
        // slither-disable-next-line divide-before-multiply
        uint256 price = msg.value / r.numModels;
        if (price * r.numModels != msg.value || price > type(uint80).max) {
            revert ModelsBadPayment(msg.value, r.numModels);
        }
        uint256 minimum = _g.minModelPrice;
        if (price < minimum) revert ModelsPriceBelowMinimum(price, minimum);
        uint256[] memory weights = _weights(r.env.length, r.weights);
        bool sharing = r.metric == Metric.Sharing;
        Scan memory s = Scan({
            domain: r.domain,
            minA: r.minReputation,
            minB: sharing ? r.minRating : r.minModelReputation,
            // No self-dealing: the requester's own models are skipped (owner id 0 never exists).
            selfId: umc.workerId(msg.sender),
            env: _envOf(r.env),
            weights: weights
        });
        // The pool owners' ids (and, for Eq. 16-19, their model-sharing counters): the scan
        // needs nothing else of them.
        (uint256[] memory ids, uint256[] memory cs) = umc.candidateIds(r.domain, SHARING, sharing);
        (uint256[] memory idx, uint256[] memory qs, uint256 count) =
            sharing ? _selectSharing(s, r.numModels, ids, cs) : _selectModel(s, r.numModels, ids);
        if (count == 0) revert ModelsNoEligibleModel(r.domain);

        allocId = ++_g.allocCount;
        _allocs[allocId] = Allocation(msg.sender, uint8(r.domain), r.metric, uint80(price));
        emit ModelsRequested(allocId, msg.sender, r.domain, r.metric, r.numModels, uint80(price));
        uint32[] memory owners = new uint32[](count);
        uint256 word = 0;
        for (uint256 i; i < count; ++i) {
            // idx[i] = list position << 64 | pool position << 32 | model id: the model was read
            // from the list of the owner at that pool position, so ids[pool position] is its owner.
            uint256 modelId = idx[i] & ID_MASK;
            uint32 ownerId = uint32(ids[uint32(idx[i] >> 32)]);
            owners[i] = ownerId;
            // modelId < 2^32 (ids are listed as uint32), so the entry never spills over.
            word |= modelId << (32 * (i % MODELS_PER_WORD));
            if (i % MODELS_PER_WORD == MODELS_PER_WORD - 1 || i == count - 1) {
                _allocModels[allocId][i / MODELS_PER_WORD] = word;
                word = 0;
            }
            _models[(uint256(ownerId) << 8) | r.domain][idx[i] >> 64].allocCount += 1;
            _payOwner(ownerId, price);
        }
        // The owners' model-sharing counters (A, Ac, E of Eq. 17-18) in one UMC call for all
        // the models, in allocation order (one WorkerInfoUpdated per model, as one updateInfo
        // call per model emitted); it returns the owners' addresses.
        // The UMC is the immutable platform registry set at construction; updateInfoBatch makes
        // no external call, so no re-entry can observe this allocation half written.
        // slither-disable-next-line reentrancy-no-eth
        address[] memory addrs = umc.updateInfoBatch(owners, r.domain, SHARING, SHARED, 0);
        for (uint256 i; i < count; ++i) {
            emit ModelAllocated(allocId, idx[i] & ID_MASK, addrs[i], qs[i] >> 32);
            emit PaymentCredited(addrs[i], allocId, price); // credited by _payOwner above
        }
        _credit(msg.sender, allocId, (r.numModels - count) * price);
    }

    /**
     * @dev The requester reviews an allocated model once (`review` in [0, 5]): updates the
     * model's reputation (Eq. 11), its owner's (Eq. 10) and the owner's model-sharing rating.
     * Requirements: caller made allocation `allocId`; the model is in it, not yet reviewed.
     * Emits a {ModelReviewed} event.
     */
    function updateModelRep(uint256 allocId, uint256 modelId, uint8 review) external {
        Allocation storage a = _allocs[allocId];
        if (a.requester != msg.sender) revert ModelsNotAllocationRequester(allocId, msg.sender);
        (uint256 k, uint256 word, uint256 bit) = _findModel(allocId, modelId);
        if (bit == 0 || word & bit != 0) revert ModelsNotAllocated(allocId, modelId);
        if (review > QoSMath.REVIEW_MAX) revert ModelsBadReview(review);
        _allocModels[allocId][k] = word | bit;
        (Model storage m, uint32 ownerId,) = _locate(modelId);
        m.totalReview += review;
        _owners[ownerId].totalReview += review;
        uint32[] memory one = new uint32[](1);
        one[0] = ownerId;
        // Only the owner's address is needed here, not its counters.
        // slither-disable-next-line unused-return
        (uint256[] memory words,) = umc.profiles(one, a.domain, SHARING);
        umc.updateInfo(words[0].addr(), a.domain, SHARING, REVIEWED, review);
        emit ModelReviewed(allocId, modelId, review);
    }

    /**
     * @dev Sends the caller's credited balance (pull payment; CEI plus reentrancy guard).
     * Requirements: a positive credit. Emits a {Withdrawn} event.
     */
    function withdraw() external nonReentrant {
        OwnerRecord storage o = _owners[umc.workerId(msg.sender)];
        uint256 earned = o.credit;
        uint256 amount = _credits[msg.sender] + earned;
        if (amount == 0) revert ModelsNothingToWithdraw(msg.sender);
        _credits[msg.sender] = 0;
        if (earned != 0) o.credit = 0;
        emit Withdrawn(msg.sender, amount);
        (bool ok,) = msg.sender.call{value: amount}("");
        if (!ok) revert ModelsTransferFailed(msg.sender, amount);
    }

    // ---------------------------------------------------------------------------- views

    /// @dev Models listed so far (ids 1..modelCount).
    function modelCount() external view returns (uint256) {
        return _g.modelCount;
    }

    /// @dev Allocations made so far (ids 1..allocCount).
    function allocCount() external view returns (uint256) {
        return _g.allocCount;
    }

    /// @dev Least price per allocated model (wei, >= 1).
    function minModelPrice() external view returns (uint256) {
        return _g.minModelPrice;
    }

    /// @dev Models one owner may list (all domains together).
    function maxModelsPerOwner() external view returns (uint32) {
        return _g.maxModelsPerOwner;
    }

    /// @dev Whether model `modelId` is in allocation `allocId`, and reviewed.
    function allocState(uint256 allocId, uint256 modelId) external view returns (AllocState) {
        (, uint256 word, uint256 bit) = _findModel(allocId, modelId);
        if (bit == 0) return AllocState.None;
        return word & bit != 0 ? AllocState.Reviewed : AllocState.Allocated;
    }

    function getModel(uint256 modelId)
        external
        view
        returns (ModelView memory model, string memory cid, uint32[] memory env)
    {
        (Model storage m, uint32 ownerId, uint8 domain) = _locate(modelId);
        uint32[] memory one = new uint32[](1);
        one[0] = ownerId;
        // Only the owner's address is needed here, not its counters.
        // slither-disable-next-line unused-return
        (uint256[] memory words,) = umc.profiles(one, domain, SHARING);
        (uint8 envLen, uint128 head) = (m.envLen, m.envHead);
        model = ModelView(words[0].addr(), domain, envLen, m.allocCount, m.totalReview);
        env = new uint32[](envLen);
        for (uint256 j; j < envLen; ++j) {
            env[j] = uint32(_attr(modelId, head, j));
        }
        cid = _cids[modelId];
    }

    /// @dev What `account` can withdraw: refunds of unfilled slots plus, for a model owner,
    /// the prices of its allocated models.
    function credits(address account) external view returns (uint256) {
        return _credits[account] + _owners[umc.workerId(account)].credit;
    }

    /// @dev Eq. 10 totals of the owner `owner` (allocations of all its models, review sum).
    function ownerRep(address owner) external view returns (OwnerRep memory) {
        OwnerRecord memory o = _owners[umc.workerId(owner)];
        return OwnerRep(o.allocCount, o.totalReview);
    }

    function getAllocation(uint256 allocId) external view returns (Allocation memory) {
        return _allocs[allocId];
    }

    /// @dev Every model ever listed in `domain`, in listing order (thesis Domain Models). Its
    /// gas grows with the domain's models, so past some thousands an eth_call runs out of gas:
    /// read {domainModelsPage} instead (kept for small domains and existing callers).
    function domainModels(uint32 domain) external view returns (uint32[] memory) {
        return _domainModels[domain];
    }

    /**
     * @dev The models of `domain` at positions [offset, offset + count) of its listing order
     * (as {UsersManager.getWorkers} pages workers) and how many it has in all: the page is
     * shorter at the end and empty past it, and its gas is bounded by `count`.
     */
    function domainModelsPage(uint32 domain, uint256 offset, uint256 count)
        external
        view
        returns (uint32[] memory page, uint256 total)
    {
        uint32[] storage list = _domainModels[domain];
        total = list.length;
        uint256 n = offset < total ? total - offset : 0;
        if (n > count) n = count;
        page = new uint32[](n);
        for (uint256 i; i < n; ++i) {
            page[i] = list[offset + i]; // offset + i < total
        }
    }

    // ---------------------------------------------------------------------------- internal

    /// @dev Eq. 10-13 over the models of the pool owners `ids`: Rep_i (owner totals) and Rep_m
    /// (model totals) filter and rank. Returns entries (pool position << 32 | model id) and
    /// keys (QoS << 32 | ~id), best first.
    function _selectModel(Scan memory s, uint256 k, uint256[] memory ids)
        internal
        view
        returns (uint256[] memory idx, uint256[] memory qs, uint256 count)
    {
        uint256 n = ids.length;
        uint256[] memory repI = new uint256[](n);
        uint256[] memory found = new uint256[](n);
        uint256 used = 0;
        for (uint256 i; i < n; ++i) {
            uint256 ownerId = ids[i];
            if (ownerId == s.selfId) continue;
            uint256 o = _rawOwner(ownerId);
            uint256 rep = QoSMath.rating(uint40(o >> 40), uint40(o)); // totalReview, allocCount
            if (rep < s.minA) continue;
            repI[i] = rep;
            (found, used) = _collect(found, used, (ownerId << 8) | s.domain, i, s.env, s.weights);
        }
        idx = new uint256[](k);
        qs = new uint256[](k);
        uint256 minB = s.minB;
        for (uint256 t; t < used; ++t) {
            uint256 f = found[t];
            // Rep_m from the model's totals: entry bits 128-167 allocCount, 168-207 totalReview.
            uint256 repM = QoSMath.rating(uint40(f >> 168), uint40(f >> 128));
            if (repM < minB) continue;
            count = _rank(idx, qs, count, f, (repI[uint32(f >> 32)] * repM) / (ONE + uint56(f >> 72)));
        }
    }

    /// @dev Eq. 16-19, 22-23 over the models of the pool owners `ids` (their model-sharing
    /// counters `cs`). N_max (Eq. 16) is taken over the owners with an eligible model, so the
    /// QoS waits for a first pass: it reads each owner's list and models once and keeps the
    /// models of d attributes with their distance; the second pass ranks them.
    function _selectSharing(Scan memory s, uint256 k, uint256[] memory ids, uint256[] memory cs)
        internal
        view
        returns (uint256[] memory idx, uint256[] memory qs, uint256 count)
    {
        uint256 n = ids.length;
        uint256 nMax = 0;
        uint256[] memory part = new uint256[](n); // E << 64 | Rep * R (< 1e12) per eligible owner
        uint256[] memory found = new uint256[](n);
        uint256 used = 0;
        for (uint256 i; i < n; ++i) {
            uint256 ownerId = ids[i];
            if (ownerId == s.selfId) continue;
            uint256 c = cs[i];
            uint256 rep = QoSMath.reputation(c.assigned(), c.accepted(), c.completed());
            uint256 rat = QoSMath.rating(c.ratingSum(), c.ratingCount());
            if (rep < s.minA || rat < s.minB) continue;
            uint256 first = used;
            (found, used) = _collect(found, used, (ownerId << 8) | s.domain, i, s.env, s.weights);
            if (used == first) continue; // no model of d attributes: not eligible
            uint256 ex = c.completed();
            if (ex > nMax) nMax = ex;
            part[i] = (ex << 64) | (rep * rat);
        }
        idx = new uint256[](k);
        qs = new uint256[](k);
        for (uint256 t; t < used; ++t) {
            uint256 f = found[t];
            uint256 p = part[uint32(f >> 32)];
            uint256 top = QoSMath.expertise(p >> 64, nMax) * uint64(p);
            count = _rank(idx, qs, count, f, top / ((ONE + uint56(f >> 72)) * ONE));
        }
    }

    /// @dev Appends to `found` (its first `used` entries taken; grown when full) the models of
    /// owner list `key` (the owner at pool position `pos`) with env.length attributes, in
    /// listing order, as: model totals (allocCount | totalReview << 40) << 128 | distance << 72
    /// | list position << 64 | pos << 32 | model id. Each model is one SLOAD, the list's length
    /// comes with its first model.
    function _collect(
        uint256[] memory found,
        uint256 used,
        uint256 key,
        uint256 pos,
        uint256[] memory env,
        uint256[] memory weights
    ) internal view returns (uint256[] memory, uint256) {
        uint256 d = env.length;
        mapping(uint256 => Model) storage list = _models[key];
        uint256 m = _rawModel(list, 0);
        uint256 len = uint8(m >> 32); // listLength, <= MAX_MODELS_PER_OWNER
        unchecked {
            // j < len <= 16 and used < found.length (grown before it is reached): no overflow.
            for (uint256 j; j < len; ++j) {
                if (j != 0) m = _rawModel(list, j);
                if (uint8(m >> 40) != d) continue; // envLen
                if (used == found.length) found = _grow(found);
                uint256 mid = m & ID_MASK;
                // distance < 2^56 (_distance), j < 2^8, pos < 2^32, mid < 2^32: no overlap.
                found[used++] = (uint256(uint80(m >> 48)) << 128) | (_distance(mid, m >> 128, env, weights) << 72)
                    | (j << 64) | (pos << 32) | mid;
            }
        }
        return (found, used);
    }

    /// @dev Ranks entry `f` (list position << 64 | pool position << 32 | model id in its low
    /// 72 bits) with QoS `q` (< 2^64) into the top-k arrays: key q << 32 | ~id, so equal QoS
    /// goes to the lower id.
    function _rank(uint256[] memory idx, uint256[] memory qs, uint256 count, uint256 f, uint256 q)
        internal
        pure
        returns (uint256)
    {
        uint256 mid = f & ID_MASK;
        // q < 2^64 and mid < 2^32: the key fits, ID_MASK - mid >= 0.
        return QoSMath.insertTop(idx, qs, count, uint72(f), (q << 32) | (ID_MASK - mid));
    }

    /// @dev The storage word of record `j` of owner list `list`, the {Model} fields from the
    /// low bits: modelId 0-31, listLength 32-39, envLen 40-47, allocCount 48-87, totalReview
    /// 88-127, envHead 128-255 (one SLOAD, no memory copy of the struct).
    function _rawModel(mapping(uint256 => Model) storage list, uint256 j) internal view returns (uint256 w) {
        Model storage m = list[j];
        assembly ("memory-safe") {
            w := sload(m.slot)
        }
    }

    /// @dev The storage word of owner `ownerId`'s {OwnerRecord}: allocCount 0-39, totalReview
    /// 40-79, modelCount 80-111, credit 112-255.
    function _rawOwner(uint256 ownerId) internal view returns (uint256 w) {
        OwnerRecord storage o = _owners[uint32(ownerId)];
        assembly ("memory-safe") {
            w := sload(o.slot)
        }
    }

    /// @dev Locates `modelId` among the models of allocation `allocId`: the word index `k`,
    /// that word and the entry's reviewed bit (0 when the model is not in the allocation).
    function _findModel(uint256 allocId, uint256 modelId)
        internal
        view
        returns (uint256 k, uint256 word, uint256 bit)
    {
        for (uint256 i; i < MAX_MODELS; ++i) {
            uint256 e = i % MODELS_PER_WORD;
            if (e == 0) {
                k = i / MODELS_PER_WORD;
                word = _allocModels[allocId][k];
            }
            uint256 id = (word >> (32 * e)) & ID_MASK;
            if (id == 0) break; // entries are filled in order; model ids are >= 1
            if (id == modelId) return (k, word, 1 << (REVIEWED_SHIFT + e));
        }
        return (0, 0, 0);
    }

    /// @dev Stores model `modelId` (< 2^32) of owner `ownerId` in `domain` with `envLen`
    /// attributes (the first four packed in `head`) at the end of the owner's list of the
    /// domain: one new slot, plus the list's length in its first record (fewer than 256
    /// entries: at most MAX_MODELS_PER_OWNER are listed), and where it is for lookups by id.
    function _listModel(uint32 ownerId, uint256 domain, uint256 modelId, uint256 envLen, uint256 head) internal {
        uint256 key = (uint256(ownerId) << 8) | domain;
        mapping(uint256 => Model) storage list = _models[key];
        uint256 n = list[0].listLength;
        list[n] = Model(uint32(modelId), n == 0 ? 1 : 0, uint8(envLen), 0, 0, uint128(head));
        if (n != 0) list[0].listLength = uint8(n + 1);
        _modelAt[modelId] = (key << 8) | n;
    }

    /// @dev Where model `modelId` is (the locator {_listModel} wrote: owner list key << 8 |
    /// position): its record, its owner's id and its domain; owner id 0 and an empty record
    /// for an id that names no model.
    function _locate(uint256 modelId) internal view returns (Model storage m, uint32 ownerId, uint8 domain) {
        uint256 loc = _modelAt[modelId];
        m = _models[loc >> 8][loc & 0xff];
        ownerId = uint32(loc >> 16);
        domain = uint8(loc >> 8);
    }

    /// @dev A copy of `a` with twice its length (plus one), for a buffer that fills up.
    function _grow(uint256[] memory a) internal pure returns (uint256[] memory b) {
        b = new uint256[](2 * a.length + 1);
        for (uint256 j; j < a.length; ++j) b[j] = a[j];
    }

    /// @dev The request's environment attributes, copied once from calldata.
    function _envOf(uint32[] calldata env) internal pure returns (uint256[] memory out) {
        out = new uint256[](env.length);
        for (uint256 j; j < env.length; ++j) out[j] = env[j];
    }

    /// @dev Eq. 13 / Eq. 22: sum_n w_n |F_n^m - F_n^r| (exact; weights scaled by 1e6).
    /// `env` and `weights` have the same length (_weights), at most MAX_ENV_DIMS.
    function _distance(uint256 modelId, uint256 head, uint256[] memory env, uint256[] memory weights)
        internal
        view
        returns (uint256 s)
    {
        uint256 d = env.length;
        // Attributes 0-3 from the model word (no SLOAD); no bounds checks: j < d = both lengths.
        // No overflow: each weight is <= 1e6 (they sum to ONE) and |a - b| < 2^32, so a term is
        // < 2^52 and the sum of at most MAX_ENV_DIMS = 12 terms is < 2^56.
        assembly ("memory-safe") {
            let n := d
            if gt(n, 4) { n := 4 }
            for { let j := 0 } lt(j, n) { j := add(j, 1) } {
                let a := and(shr(shl(5, j), head), 0xffffffff)
                let b := mload(add(env, shl(5, add(j, 1))))
                let diff := sub(a, b)
                if lt(a, b) { diff := sub(b, a) }
                s := add(s, mul(mload(add(weights, shl(5, add(j, 1)))), diff))
            }
        }
        if (d > 4) {
            uint256 word = 0;
            unchecked {
                for (uint256 j = 4; j < d; ++j) {
                    if ((j - 4) & 7 == 0) word = _envTail[modelId][(j - 4) >> 3]; // one SLOAD per 8
                    uint256 a = uint32(word >> (32 * ((j - 4) & 7)));
                    uint256 b = env[j];
                    s += weights[j] * (a >= b ? a - b : b - a);
                }
            }
        }
    }

    /// @dev Environment attribute `j` of a model.
    function _attr(uint256 modelId, uint256 head, uint256 j) internal view returns (uint256) {
        if (j < 4) return uint32(head >> (32 * j));
        return uint32(_envTail[modelId][(j - 4) >> 3] >> (32 * ((j - 4) & 7)));
    }

    /// @dev Given weights (each <= 1e6, sum == 1e6) or the default: ONE / d each with the
    /// remainder on the first (qos.default_weights).
    function _weights(uint256 d, uint32[] calldata given) internal pure returns (uint256[] memory w) {
        if (d > MAX_ENV_DIMS) revert ModelsBadEnv(d);
        w = new uint256[](d);
        if (d == 0) {
            if (given.length != 0) revert ModelsBadWeights();
            return w;
        }
        if (given.length == 0) {
            // qos.default_weights: the floor of ONE / d each, the remainder on the first, so the
            // weights sum to ONE exactly (bit-exact with qos.py).
            // slither-disable-next-line divide-before-multiply
            uint256 each = ONE / d;
            for (uint256 j; j < d; ++j) w[j] = each;
            w[0] += ONE - each * d;
            return w;
        }
        if (given.length != d) revert ModelsBadWeights();
        uint256 sum = 0;
        for (uint256 j; j < d; ++j) {
            w[j] = given[j];
            sum += given[j];
        }
        if (sum != ONE) revert ModelsBadWeights();
    }

    function _credit(address account, uint256 allocId, uint256 amount) internal {
        if (amount == 0) return;
        _credits[account] += amount;
        emit PaymentCredited(account, allocId, amount);
    }

    /// @dev One allocation of a model of owner `ownerId` at `price`: Eq. 10's count and the
    /// owner's credit, in one word of its {OwnerRecord}. The credit cannot overflow: it is at
    /// most allocCount (< 2^40, checked) x price (< 2^80) < 2^144.
    function _payOwner(uint32 ownerId, uint256 price) internal {
        OwnerRecord storage o = _owners[ownerId];
        o.allocCount += 1;
        o.credit += uint144(price);
    }
}
