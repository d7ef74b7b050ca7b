// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

import {cidFor} from "../utils/CidFor.sol";
import {Vm} from "../utils/Vm.sol";
import {UsersManager} from "../../src/UsersManager.sol";
import {TasksManager} from "../../src/TasksManager.sol";
import {ModelsManager} from "../../src/ModelsManager.sol";
import {QoSMath} from "../../src/QoSMath.sol";

/**
 * @dev Drives random sequences of calls on the UMC, TMC and MMC by several actors
 * (requesters, workers, the admin, strangers). A handler function never reverts on a
 * failed platform call (the invariants run with fail_on_revert = false); what must hold is
 * recorded in ghost counters the invariant test reads:
 *  - eventViolations: a counter, credit, task, model or allocation changed without its event
 *    (every call is made under vm.recordLogs and the state before/after is compared with
 *    the logs);
 *  - allocationMismatches: an allocation differed from the reference greedy top-k computed
 *    here by brute force (full ordering by the QoS formulas over the candidate pool);
 *  - intrusions: a call by an actor without the right (stranger on an admin function,
 *    another requester's task, another worker's offer, ...) succeeded.
 * Escrow of every task is tracked so the balance invariants can be checked.
 */
contract PlatformHandler {
    Vm internal constant vm = Vm(address(uint160(uint256(keccak256("hevm cheat code")))));
    uint256 internal constant ONE = 1e6;
    uint32 internal constant DOMAIN = 7;

    UsersManager public immutable umc;
    TasksManager public immutable tmc;
    ModelsManager public immutable mmc;
    address public immutable admin;

    address[] public requesters;
    address[] public workers;
    address[] public strangers;
    /// Every account that may hold a credit (requesters and workers).
    address[] public payees;

    uint256 public eventViolations;
    uint256 public allocationMismatches;
    uint256 public intrusions;
    uint256 public allocationsChecked;
    uint256 public modelAllocationsChecked;
    uint256 public intrusionAttempts;
    uint256 public calls;
    mapping(string => uint256) public violationsBy;

    uint256 internal _cidNonce;

    constructor(UsersManager umc_, TasksManager tmc_, ModelsManager mmc_, address admin_) {
        (umc, tmc, mmc, admin) = (umc_, tmc_, mmc_, admin_);
        for (uint256 i; i < 2; ++i) requesters.push(address(uint160(0xB000 + i)));
        for (uint256 i; i < 6; ++i) workers.push(address(uint160(0xC000 + i)));
        for (uint256 i; i < 2; ++i) strangers.push(address(uint160(0xD000 + i)));
        for (uint256 i; i < requesters.length; ++i) payees.push(requesters[i]);
        for (uint256 i; i < workers.length; ++i) payees.push(workers[i]);
    }

    /// @dev Registers the actors (called once by the test's setUp).
    function init() external {
        for (uint256 i; i < requesters.length; ++i) {
            vm.prank(requesters[i]);
            umc.addRequester();
            vm.prank(admin);
            umc.approveRequester(requesters[i]);
            vm.deal(requesters[i], 1e30);
        }
        for (uint256 i; i < workers.length; ++i) {
            vm.prank(workers[i]);
            // two workers share cores so QoS ties occur (ties go to the lower id)
            umc.addWorker(1 << DOMAIN, uint16(4 + 6 * (i % 4)), 32, uint8(1 + (i % 2)));
            vm.prank(admin);
            umc.approveWorker(workers[i]);
        }
    }

    // =========================================================== state snapshot + events

    struct Snap {
        uint256[] counters; // per worker: training then sharing counter words
        uint256[] tmcCredits;
        uint256[] mmcCredits;
        uint256 taskCount;
        uint256 modelCount;
        uint256 allocCount;
    }

    function _counterWord(address w, uint8 t) internal view returns (uint256) {
        UsersManager.Counters memory c = umc.counters(w, DOMAIN, t);
        return uint256(c.assigned) | (uint256(c.accepted) << 48) | (uint256(c.completed) << 96)
            | (uint256(c.ratingSum) << 144) | (uint256(c.ratingCount) << 192);
    }

    function _snap() internal view returns (Snap memory s) {
        uint256 n = workers.length;
        s.counters = new uint256[](2 * n);
        for (uint256 i; i < n; ++i) {
            s.counters[i] = _counterWord(workers[i], 0);
            s.counters[n + i] = _counterWord(workers[i], 1);
        }
        s.tmcCredits = new uint256[](payees.length);
        s.mmcCredits = new uint256[](payees.length);
        for (uint256 i; i < payees.length; ++i) {
            s.tmcCredits[i] = tmc.credits(payees[i]);
            s.mmcCredits[i] = mmc.credits(payees[i]);
        }
        s.taskCount = tmc.taskCount();
        s.modelCount = mmc.modelCount();
        s.allocCount = mmc.allocCount();
    }

    function _begin() internal returns (Snap memory) {
        ++calls;
        vm.recordLogs();
        return _snap();
    }

    function _violation(string memory what) internal {
        ++eventViolations;
        ++violationsBy[what];
    }

    /// @dev Every change between `before` and now must be announced by the logs: the last
    /// WorkerInfoUpdated of a worker carries its new counters; credits move by exactly the
    /// PaymentCredited minus Withdrawn amounts; each new task, model and allocation has its
    /// TaskAdded, ModelAdded and ModelsRequested event.
    function _end(Snap memory before) internal {
        Vm.Log[] memory logs = vm.getRecordedLogs();
        Snap memory afterS = _snap();
        uint256 n = workers.length;
        for (uint256 t; t < 2; ++t) {
            for (uint256 i; i < n; ++i) {
                uint256 now_ = afterS.counters[t * n + i];
                bool changed = now_ != before.counters[t * n + i];
                (bool seen, uint256 last) = _lastInfo(logs, workers[i], uint8(t));
                if (changed && (!seen || last != now_)) _violation("counters");
                if (!changed && seen && last != now_) _violation("counters-event");
            }
        }
        for (uint256 i; i < payees.length; ++i) {
            (uint256 inT, uint256 outT) = _money(logs, address(tmc), payees[i]);
            if (afterS.tmcCredits[i] + outT != before.tmcCredits[i] + inT) _violation("tmc-credits");
            (uint256 inM, uint256 outM) = _money(logs, address(mmc), payees[i]);
            if (afterS.mmcCredits[i] + outM != before.mmcCredits[i] + inM) _violation("mmc-credits");
        }
        if (afterS.taskCount - before.taskCount != _count(logs, address(tmc), TasksManager.TaskAdded.selector)) {
            _violation("taskCount");
        }
        if (afterS.modelCount - before.modelCount != _count(logs, address(mmc), ModelsManager.ModelAdded.selector)) {
            _violation("modelCount");
        }
        if (
            afterS.allocCount - before.allocCount
                != _count(logs, address(mmc), ModelsManager.ModelsRequested.selector)
        ) _violation("allocCount");
    }

    function _lastInfo(Vm.Log[] memory logs, address w, uint8 t) internal view returns (bool seen, uint256 word) {
        for (uint256 j; j < logs.length; ++j) {
            Vm.Log memory l = logs[j];
            if (
                l.emitter != address(umc) || l.topics.length != 4
                    || l.topics[0] != UsersManager.WorkerInfoUpdated.selector
                    || l.topics[1] != bytes32(uint256(uint160(w))) || uint256(l.topics[2]) != DOMAIN
                    || uint256(l.topics[3]) != t
            ) continue;
            (uint48 a, uint48 ac, uint48 e, uint48 rs, uint48 rc) =
                abi.decode(l.data, (uint48, uint48, uint48, uint48, uint48));
            seen = true;
            word = uint256(a) | (uint256(ac) << 48) | (uint256(e) << 96) | (uint256(rs) << 144) | (uint256(rc) << 192);
        }
    }

    function _money(Vm.Log[] memory logs, address emitter, address who) internal pure returns (uint256 in_, uint256 out) {
        bytes32 whoTopic = bytes32(uint256(uint160(who)));
        for (uint256 j; j < logs.length; ++j) {
            Vm.Log memory l = logs[j];
            if (l.emitter != emitter || l.topics.length < 2 || l.topics[1] != whoTopic) continue;
            if (l.topics[0] == TasksManager.PaymentCredited.selector) in_ += abi.decode(l.data, (uint256));
            else if (l.topics[0] == TasksManager.Withdrawn.selector) out += abi.decode(l.data, (uint256));
        }
    }

    function _count(Vm.Log[] memory logs, address emitter, bytes32 topic) internal pure returns (uint256 c) {
        for (uint256 j; j < logs.length; ++j) {
            if (logs[j].emitter == emitter && logs[j].topics[0] == topic) ++c;
        }
    }

    // =========================================================== helpers

    function _pick(address[] storage list, uint256 seed) internal view returns (address) {
        return list[seed % list.length];
    }

    function _task(uint256 seed) internal view returns (uint256) {
        uint256 n = tmc.taskCount();
        return n == 0 ? 0 : 1 + (seed % n);
    }

    function _try(address who, address target, bytes memory data, uint256 value) internal returns (bool ok) {
        vm.prank(who);
        (ok,) = target.call{value: value}(data);
    }

    /// @dev `who` commits `cid` (TMC.commitCid, commit-reveal) and the chain moves a block on,
    /// so that the call after may reveal it; a refused commit (not a worker) is left to the
    /// reveal's own revert. Returns the CID for the reveal.
    function _committed(address who, string memory cid) internal returns (string memory) {
        _try(who, address(tmc), abi.encodeCall(TasksManager.commitCid, (keccak256(abi.encodePacked(cid, who)))), 0);
        vm.roll(vm.getBlockNumber() + 1);
        return cid;
    }

    // =========================================================== time

    function warp(uint256 secs) external {
        vm.warp(block.timestamp + (secs % 2 days));
    }

    // =========================================================== TMC, requester side

    function addTask(uint256 who, uint8 n, uint256 reward, uint256 duration, uint32 minCores) external {
        address r = _pick(requesters, who);
        uint8 nw = uint8(1 + (n % 4));
        TasksManager.TaskParams memory p = TasksManager.TaskParams(
            DOMAIN, nw, 0, 0, minCores % 20, 0, uint40(3_660 + (duration % 3 days)), "task"
        );
        uint256 value = (1 + (reward % 1e18)) * nw;
        Snap memory s = _begin();
        _try(r, address(tmc), abi.encodeCall(TasksManager.addTask, (p)), value);
        _end(s);
    }

    function allocateTask(uint256 taskSeed, bool byAdmin) external {
        uint256 id = _task(taskSeed);
        if (id == 0) return;
        (TasksManager.Task memory t, TasksManager.Reqs memory q) = tmc.getTask(id);
        address[] memory expected = _referenceTopK(id, t, q);
        uint256 before = tmc.offerees(id).length;
        Snap memory s = _begin();
        bool ok = _try(byAdmin ? admin : t.requester, address(tmc), abi.encodeCall(TasksManager.allocateTask, (id)), 0);
        _end(s);
        if (!ok) return;
        ++allocationsChecked;
        address[] memory list = tmc.offerees(id);
        if (list.length - before != expected.length) {
            ++allocationMismatches;
            return;
        }
        for (uint256 i; i < expected.length; ++i) {
            if (list[before + i] != expected[i]) ++allocationMismatches;
        }
    }

    /// @dev Reference of allocateTask: the candidate pool's eligible workers (7.5.1), QoS by
    /// Eq. 16-21, ordered by brute force (repeatedly the best remaining: highest QoS, then
    /// lowest worker id), minus everyone offered before and the requester, first `open`.
    function _referenceTopK(uint256 id, TasksManager.Task memory t, TasksManager.Reqs memory q)
        internal
        view
        returns (address[] memory out)
    {
        address[] memory pool = umc.pool(q.domain);
        uint256 n = pool.length;
        uint256[] memory score = new uint256[](n);
        bool[] memory ok = new bool[](n);
        uint256 nMax;
        uint256 gpus = tmc.acceptedGpus();
        for (uint256 i; i < n; ++i) {
            UsersManager.Worker memory w = umc.getWorker(pool[i]);
            if (w.status != UsersManager.Status.Active || w.cpuCores < q.minCpuCores || w.ramGb < q.minRamGb) continue;
            if ((gpus >> w.gpuSeries) & 1 == 0) continue;
            UsersManager.Counters memory c = umc.counters(pool[i], q.domain, 0);
            uint256 rep = QoSMath.reputation(c.assigned, c.accepted, c.completed);
            uint256 rat = QoSMath.rating(c.ratingSum, c.ratingCount);
            if (rep < q.minReputation || rat < q.minRating) continue;
            if (c.completed > nMax) nMax = c.completed;
            ok[i] = true;
            score[i] = rep * rat * QoSMath.atanFixed(uint256(tmc.w1()) * w.cpuCores);
        }
        address[] memory offered = tmc.offerees(id);
        uint256 live;
        for (uint256 j; j < offered.length; ++j) {
            TasksManager.Offer memory o = tmc.getOffer(id, offered[j]);
            if (o.state == TasksManager.OfferState.Offered && block.timestamp <= o.expiry) ++live;
        }
        for (uint256 i; i < n; ++i) {
            if (!ok[i]) continue;
            if (pool[i] == t.requester) ok[i] = false;
            for (uint256 j; j < offered.length; ++j) {
                if (offered[j] == pool[i]) ok[i] = false;
            }
            if (!ok[i]) continue;
            UsersManager.Counters memory c = umc.counters(pool[i], q.domain, 0);
            score[i] = (QoSMath.expertise(c.completed, nMax) * score[i]) / 1e18;
        }
        uint256 open = t.numWorkers - live - t.filled;
        uint256 room = 64 - t.offerCount;
        if (open > room) open = room;
        address[] memory buf = new address[](open);
        uint256 k;
        for (; k < open; ++k) {
            (bool found, uint256 best) = (false, 0);
            for (uint256 i; i < n; ++i) {
                if (!ok[i]) continue;
                if (
                    !found || score[i] > score[best]
                        || (score[i] == score[best] && umc.workerId(pool[i]) < umc.workerId(pool[best]))
                ) (found, best) = (true, i);
            }
            if (!found) break;
            buf[k] = pool[best];
            ok[best] = false;
        }
        out = new address[](k);
        for (uint256 i; i < k; ++i) out[i] = buf[i];
    }

    function reviewOutcome(uint256 taskSeed, uint256 workerSeed, uint8 review, bool accepted) external {
        uint256 id = _task(taskSeed);
        if (id == 0) return;
        (TasksManager.Task memory t,) = tmc.getTask(id);
        address[] memory list = tmc.offerees(id);
        if (list.length == 0) return;
        address w = list[workerSeed % list.length];
        Snap memory s = _begin();
        _try(t.requester, address(tmc), abi.encodeCall(TasksManager.reviewOutcome, (id, w, review % 6, accepted)), 0);
        _end(s);
    }

    function updateTaskStatus(uint256 taskSeed, bool close, uint256 callerSeed) external {
        uint256 id = _task(taskSeed);
        if (id == 0) return;
        (TasksManager.Task memory t,) = tmc.getTask(id);
        address caller = t.requester;
        address[] memory list = tmc.offerees(id);
        if (close && list.length != 0 && callerSeed % 2 == 1) caller = list[callerSeed % list.length];
        TasksManager.TaskStatus st = close ? TasksManager.TaskStatus.Closed : TasksManager.TaskStatus.Cancelled;
        Snap memory s = _begin();
        _try(caller, address(tmc), abi.encodeCall(TasksManager.updateTaskStatus, (id, st)), 0);
        _end(s);
    }

    function cancelOpenSlots(uint256 taskSeed) external {
        uint256 id = _task(taskSeed);
        if (id == 0) return;
        (TasksManager.Task memory t,) = tmc.getTask(id);
        Snap memory s = _begin();
        _try(t.requester, address(tmc), abi.encodeCall(TasksManager.cancelOpenSlots, (id)), 0);
        _end(s);
    }

    // =========================================================== TMC, worker side

    function workerAct(uint256 taskSeed, uint256 workerSeed, uint8 action) external {
        uint256 id = _task(taskSeed);
        if (id == 0) return;
        address[] memory list = tmc.offerees(id);
        address w = list.length != 0 && workerSeed % 4 != 0 ? list[workerSeed % list.length] : _pick(workers, workerSeed);
        bytes memory data;
        uint8 a = action % 4;
        if (a == 0) data = abi.encodeCall(TasksManager.acceptOffer, (id));
        else if (a == 1) data = abi.encodeCall(TasksManager.declineOffer, (id));
        else if (a == 2) data = abi.encodeCall(TasksManager.abandonOffer, (id));
        else data = abi.encodeCall(TasksManager.submitOutcome, (id, _committed(w, cidFor(abi.encodePacked("bafy", ++_cidNonce)))));
        Snap memory s = _begin();
        _try(w, address(tmc), data, 0);
        _end(s);
    }

    /// @dev Moves one offer of a task one step along the paid path (accept, submit, then the
    /// requester's accepting review), so that the campaign reaches payments and their events,
    /// not only the checks in front of them (a mutation check found it rarely did).
    function advance(uint256 taskSeed, uint256 workerSeed, uint8 review) external {
        uint256 id = _task(taskSeed);
        if (id == 0) return;
        address[] memory list = tmc.offerees(id);
        if (list.length == 0) return;
        address w = list[workerSeed % list.length];
        TasksManager.OfferState st = tmc.getOffer(id, w).state;
        address who = w;
        bytes memory data;
        if (st == TasksManager.OfferState.Offered) {
            data = abi.encodeCall(TasksManager.acceptOffer, (id));
        } else if (st == TasksManager.OfferState.Accepted) {
            data = abi.encodeCall(TasksManager.submitOutcome, (id, _committed(w, cidFor(abi.encodePacked("bafy", ++_cidNonce)))));
        } else if (st == TasksManager.OfferState.Submitted) {
            (TasksManager.Task memory t,) = tmc.getTask(id);
            who = t.requester;
            data = abi.encodeCall(TasksManager.reviewOutcome, (id, w, review % 6, true));
        } else {
            return;
        }
        Snap memory s = _begin();
        _try(who, address(tmc), data, 0);
        _end(s);
    }

    /// @dev A submitted offer of any task, searching from the task that seed picks (0 if none).
    function _anySubmitted(uint256 seed) internal view returns (uint256 id, address worker) {
        uint256 n = tmc.taskCount();
        for (uint256 i; i < n; ++i) {
            uint256 cand = 1 + ((seed + i) % n);
            address[] memory list = tmc.offerees(cand);
            address w = _submitted(cand, list, address(0));
            if (w != address(0)) return (cand, w);
        }
    }

    /// @dev An accepted (not yet submitted) offer among the 8 tasks from the one that seed picks
    /// on (0 if none; bounded so that a long campaign's call stays cheap).
    function _anyAccepted(uint256 seed) internal view returns (uint256 id, address worker) {
        uint256 n = tmc.taskCount();
        for (uint256 i; i < n && i < 8; ++i) {
            uint256 cand = 1 + ((seed % n + i) % n); // seed may be near 2^256
            address[] memory list = tmc.offerees(cand);
            for (uint256 j; j < list.length; ++j) {
                if (tmc.getOffer(cand, list[j]).state == TasksManager.OfferState.Accepted) return (cand, list[j]);
            }
        }
    }

    function _submitted(uint256 id, address[] memory list, address fallback_) internal view returns (address) {
        for (uint256 i; i < list.length; ++i) {
            if (tmc.getOffer(id, list[i]).state == TasksManager.OfferState.Submitted) return list[i];
        }
        return fallback_;
    }

    function withdraw(uint256 who, bool models) external {
        address a = payees[who % payees.length];
        uint256 before = a.balance;
        uint256 owed = models ? mmc.credits(a) : tmc.credits(a);
        Snap memory s = _begin();
        bool ok = _try(a, models ? address(mmc) : address(tmc), abi.encodeWithSignature("withdraw()"), 0);
        _end(s);
        if (ok && a.balance - before != owed) _violation("withdraw-amount");
    }

    // =========================================================== MMC

    function addModel(uint256 who, uint32 a, uint32 b, bool outcome) external {
        address w = _pick(workers, who);
        string memory cid = cidFor(abi.encodePacked("model", ++_cidNonce));
        if (outcome && _cidNonce > 1) cid = cidFor(abi.encodePacked("bafy", (a % _cidNonce) + 1)); // an outcome CID
        uint32[] memory env = new uint32[](2);
        (env[0], env[1]) = (a % 8, b % 8);
        _committed(w, cid); // an outcome CID's record outweighs any commitment
        Snap memory s = _begin();
        _try(w, address(mmc), abi.encodeCall(ModelsManager.addModel, (cid, "d", DOMAIN, env)), 0);
        _end(s);
    }

    function allocateModel(uint256 who, uint8 n, uint256 price, bool sharing, uint32 a, uint32 b) external {
        address r = _pick(requesters, who);
        uint8 k = uint8(1 + (n % 4));
        uint32[] memory env = new uint32[](2);
        (env[0], env[1]) = (a % 8, b % 8);
        ModelsManager.Metric metric = sharing ? ModelsManager.Metric.Sharing : ModelsManager.Metric.Model;
        ModelsManager.ModelRequest memory req =
            ModelsManager.ModelRequest(DOMAIN, k, metric, 0, 0, 0, env, new uint32[](0));
        uint256[] memory expected = _referenceModels(req);
        Snap memory s = _begin();
        vm.prank(r);
        (bool ok, bytes memory ret) = address(mmc).call{value: (1 + (price % 1e18)) * k}(
            abi.encodeCall(ModelsManager.allocateModel, (req))
        );
        Vm.Log[] memory logs = vm.getRecordedLogs();
        // re-record so _end still sees the logs: compare model ids from ModelAllocated first
        if (ok) {
            ++modelAllocationsChecked;
            uint256 allocId = abi.decode(ret, (uint256));
            uint256 m;
            for (uint256 j; j < logs.length; ++j) {
                if (logs[j].emitter != address(mmc) || logs[j].topics[0] != ModelsManager.ModelAllocated.selector) continue;
                if (uint256(logs[j].topics[1]) != allocId) continue;
                if (m >= expected.length || uint256(logs[j].topics[2]) != expected[m]) ++allocationMismatches;
                ++m;
            }
            if (m != expected.length) ++allocationMismatches;
        } else if (expected.length != 0) {
            ++allocationMismatches;
        }
        _endWith(s, logs);
    }

    function _endWith(Snap memory s, Vm.Log[] memory logs) internal {
        // replay: _end reads the recorded logs; emit nothing, so check with the saved ones
        _checkAgainst(s, logs);
    }

    function _checkAgainst(Snap memory before, Vm.Log[] memory logs) internal {
        Snap memory afterS = _snap();
        uint256 n = workers.length;
        for (uint256 t; t < 2; ++t) {
            for (uint256 i; i < n; ++i) {
                uint256 now_ = afterS.counters[t * n + i];
                (bool seen, uint256 last) = _lastInfo(logs, workers[i], uint8(t));
                if (now_ != before.counters[t * n + i] && (!seen || last != now_)) _violation("counters");
            }
        }
        for (uint256 i; i < payees.length; ++i) {
            (uint256 inM, uint256 outM) = _money(logs, address(mmc), payees[i]);
            if (afterS.mmcCredits[i] + outM != before.mmcCredits[i] + inM) _violation("mmc-credits");
        }
        if (
            afterS.allocCount - before.allocCount
                != _count(logs, address(mmc), ModelsManager.ModelsRequested.selector)
        ) _violation("allocCount");
    }

    /// @dev Reference of allocateModel (default weights, no thresholds): QoS of every model of
    /// the pool owners with the right number of attributes by Eq. 10-13 or Eq. 16-19, 22-23,
    /// ordered by brute force (highest QoS, then lowest model id), first numModels.
    function _referenceModels(ModelsManager.ModelRequest memory req) internal view returns (uint256[] memory out) {
        address[] memory pool = umc.pool(DOMAIN);
        uint256 total = mmc.modelCount();
        uint256[] memory score = new uint256[](total + 1);
        bool[] memory ok = new bool[](total + 1);
        uint256 nMax;
        if (req.metric == ModelsManager.Metric.Sharing) {
            for (uint256 i; i < pool.length; ++i) {
                if (_hasModel(pool[i], total)) {
                    uint256 e = umc.counters(pool[i], DOMAIN, 1).completed;
                    if (e > nMax) nMax = e;
                }
            }
        }
        for (uint256 id = 1; id <= total; ++id) {
            (ModelsManager.ModelView memory m,, uint32[] memory env) = mmc.getModel(id);
            if (!_inPool(pool, m.owner) || m.domain != DOMAIN || env.length != 2) continue;
            uint256 dist = 5e5 * _absDiff(env[0], req.env[0]) + 5e5 * _absDiff(env[1], req.env[1]);
            ok[id] = true;
            if (req.metric == ModelsManager.Metric.Model) {
                ModelsManager.OwnerRep memory o = mmc.ownerRep(m.owner);
                uint256 repI = QoSMath.rating(o.totalReview, o.allocCount);
                uint256 repM = QoSMath.rating(m.totalReview, m.allocCount);
                score[id] = (repI * repM) / (ONE + dist);
            } else {
                UsersManager.Counters memory c = umc.counters(m.owner, DOMAIN, 1);
                uint256 rep = QoSMath.reputation(c.assigned, c.accepted, c.completed);
                uint256 rat = QoSMath.rating(c.ratingSum, c.ratingCount);
                score[id] = (QoSMath.expertise(c.completed, nMax) * rep * rat) / ((ONE + dist) * ONE);
            }
        }
        uint256[] memory buf = new uint256[](req.numModels);
        uint256 k;
        for (; k < req.numModels; ++k) {
            uint256 best;
            for (uint256 id = 1; id <= total; ++id) {
                if (ok[id] && (best == 0 || score[id] > score[best])) best = id; // ascending ids: ties keep the lower
            }
            if (best == 0) break;
            buf[k] = best;
            ok[best] = false;
        }
        out = new uint256[](k);
        for (uint256 i; i < k; ++i) out[i] = buf[i];
    }

    function _hasModel(address owner, uint256 total) internal view returns (bool) {
        for (uint256 id = 1; id <= total; ++id) {
            (ModelsManager.ModelView memory m,, uint32[] memory env) = mmc.getModel(id);
            if (m.owner == owner && m.domain == DOMAIN && env.length == 2) return true;
        }
        return false;
    }

    function _inPool(address[] memory pool, address a) internal pure returns (bool) {
        for (uint256 i; i < pool.length; ++i) if (pool[i] == a) return true;
        return false;
    }

    function _absDiff(uint256 a, uint256 b) internal pure returns (uint256) {
        return a >= b ? a - b : b - a;
    }

    function updateModelRep(uint256 allocSeed, uint256 modelSeed, uint8 review) external {
        uint256 n = mmc.allocCount();
        uint256 m = mmc.modelCount();
        if (n == 0 || m == 0) return;
        uint256 allocId = 1 + (allocSeed % n);
        ModelsManager.Allocation memory al = mmc.getAllocation(allocId);
        Snap memory s = _begin();
        _try(al.requester, address(mmc), abi.encodeCall(ModelsManager.updateModelRep, (allocId, 1 + (modelSeed % m), review % 6)), 0);
        _end(s);
    }

    // =========================================================== roles

    /**
     * @dev An actor tries something only another role may do; it must revert. Actors:
     * strangers (no role), workers and requesters acting on what is not theirs.
     */
    function intrude(uint256 actorSeed, uint8 action, uint256 targetSeed) external {
        uint256 id = _task(targetSeed);
        uint8 a = action % 11;
        address actor;
        bytes memory data;
        address target = address(tmc);
        if (a == 0) {
            actor = _pick(strangers, actorSeed);
            target = address(umc);
            data = abi.encodeCall(UsersManager.setAdmin, (actor, true));
        } else if (a == 1) {
            actor = _pick(workers, actorSeed);
            target = address(umc);
            data = abi.encodeCall(UsersManager.updateInfo, (actor, DOMAIN, 0, 4, 0));
        } else if (a == 2) {
            target = address(umc);
            if (targetSeed % 2 == 0) {
                actor = _pick(requesters, actorSeed);
                data = abi.encodeCall(UsersManager.removeWorker, (_pick(workers, targetSeed)));
            } else {
                // a worker removing a requester, or approving one (admins only)
                actor = _pick(workers, actorSeed);
                address r = _pick(requesters, targetSeed / 2);
                data = actorSeed % 2 == 0
                    ? abi.encodeCall(UsersManager.removeRequester, (r))
                    : abi.encodeCall(UsersManager.approveRequester, (r));
            }
        } else if (a == 3) {
            actor = _pick(strangers, actorSeed);
            data = abi.encodeCall(TasksManager.setConfig, (1, 1, 1));
        } else if (a == 4) {
            actor = _pick(strangers, actorSeed);
            target = address(mmc);
            data = abi.encodeCall(ModelsManager.setMinModelPrice, (1));
        } else {
            if (id == 0) return;
            (TasksManager.Task memory t,) = tmc.getTask(id);
            // another requester, or a worker, acting as this task's requester
            actor = actorSeed % 2 == 0 ? _other(requesters, t.requester, actorSeed) : _pick(workers, actorSeed);
            address[] memory list = tmc.offerees(id);
            address w = list.length == 0 ? _pick(workers, targetSeed) : list[targetSeed % list.length];
            if (a == 5) {
                data = abi.encodeCall(TasksManager.allocateTask, (id));
            } else if (a == 6) {
                // reviewing a submitted outcome of a task that is not the actor's: the offer must
                // be Submitted for the role check to be the only thing in the way, and submitted
                // offers are short-lived in a campaign, so look for one in every task
                (uint256 sid, address sw) = _anySubmitted(targetSeed);
                if (sid != 0) {
                    (id, w) = (sid, sw);
                    (t,) = tmc.getTask(id);
                    actor = actorSeed % 2 == 0 ? _other(requesters, t.requester, actorSeed) : _pick(workers, actorSeed);
                }
                data = abi.encodeCall(TasksManager.reviewOutcome, (id, sid != 0 ? w : _submitted(id, list, w), 5, true));
            } else if (a == 7) {
                data = abi.encodeCall(TasksManager.cancelOpenSlots, (id));
            } else if (a == 8) {
                // a worker answering or submitting for an offer that is not its own: the first
                // worker from actorSeed on that holds no live offer of this task (the choice of
                // call uses other bits of the seed than the choice of worker)
                actor = address(0);
                for (uint256 i; i < workers.length; ++i) {
                    address cand = workers[(actorSeed + i) % workers.length];
                    TasksManager.OfferState st = tmc.getOffer(id, cand).state;
                    if (st != TasksManager.OfferState.Offered && st != TasksManager.OfferState.Accepted) {
                        actor = cand;
                        break;
                    }
                }
                if (actor == address(0)) return;
                uint256 call_ = (actorSeed / workers.length) % 3;
                data = call_ == 0
                    ? abi.encodeCall(TasksManager.acceptOffer, (id))
                    : call_ == 1
                        ? abi.encodeCall(TasksManager.declineOffer, (id))
                        : abi.encodeCall(
                            TasksManager.submitOutcome, (id, _committed(actor, cidFor(abi.encodePacked("x", ++_cidNonce))))
                        );
            } else if (a == 10) {
                // front-running: a worker sees another worker's CID (committed a block ago, its
                // reveal pending) and commits and reveals it in this one block, ahead of the
                // producer, as its outcome (holding an accepted offer) or as its own listing:
                // commit-reveal must refuse it
                bool listing = actorSeed % 2 == 1;
                if (listing) {
                    actor = _pick(workers, actorSeed / 2);
                    target = address(mmc);
                } else {
                    (uint256 aid, address thief) = _anyAccepted(targetSeed);
                    if (aid == 0) return;
                    (id, actor) = (aid, thief);
                }
                string memory cid = cidFor(abi.encodePacked("fr", ++_cidNonce));
                _committed(_other(workers, actor, actorSeed / 2 + 1), cid); // the producer
                _try(actor, address(tmc), abi.encodeCall(TasksManager.commitCid, (keccak256(abi.encodePacked(cid, actor)))), 0);
                uint32[] memory env = new uint32[](2);
                data = listing
                    ? abi.encodeCall(ModelsManager.addModel, (cid, "d", DOMAIN, env))
                    : abi.encodeCall(TasksManager.submitOutcome, (id, cid));
            } else {
                uint256 n = mmc.allocCount();
                if (n == 0) return;
                uint256 allocId = 1 + (targetSeed % n);
                actor = _other(requesters, mmc.getAllocation(allocId).requester, actorSeed);
                target = address(mmc);
                data = abi.encodeCall(ModelsManager.updateModelRep, (allocId, 1, 5));
            }
        }
        ++intrusionAttempts;
        Snap memory s = _begin();
        if (_try(actor, target, data, 0)) ++intrusions;
        _end(s);
    }

    function _other(address[] storage list, address not_, uint256 seed) internal view returns (address) {
        address a = list[seed % list.length];
        return a == not_ ? list[(seed + 1) % list.length] : a;
    }

    // =========================================================== views for the invariants

    /// @dev Escrow the TMC must hold: the unsettled slots of every task.
    function tmcEscrow() external view returns (uint256 sum) {
        uint256 n = tmc.taskCount();
        for (uint256 id = 1; id <= n; ++id) {
            (TasksManager.Task memory t, TasksManager.Reqs memory q) = tmc.getTask(id);
            sum += uint256(t.numWorkers - t.settled) * q.reward;
        }
    }

    function creditsOf(bool models) external view returns (uint256 sum) {
        for (uint256 i; i < payees.length; ++i) sum += models ? mmc.credits(payees[i]) : tmc.credits(payees[i]);
    }

    function selectors() external pure returns (bytes4[] memory s) {
        s = new bytes4[](13);
        s[0] = this.warp.selector;
        s[1] = this.addTask.selector;
        s[2] = this.allocateTask.selector;
        s[3] = this.reviewOutcome.selector;
        s[4] = this.updateTaskStatus.selector;
        s[5] = this.cancelOpenSlots.selector;
        s[6] = this.workerAct.selector;
        s[7] = this.withdraw.selector;
        s[8] = this.addModel.selector;
        s[9] = this.allocateModel.selector;
        s[10] = this.updateModelRep.selector;
        s[11] = this.intrude.selector;
        s[12] = this.advance.selector;
    }
}
