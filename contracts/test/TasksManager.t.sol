// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

import {cidFor} from "./utils/CidFor.sol";
import {Fixture} from "./utils/Fixture.sol";
import {TasksManager} from "../src/TasksManager.sol";
import {IModelsListing} from "../src/IModelsListing.sol";
import {UsersManager} from "../src/UsersManager.sol";

/// @dev Fuzz tests of every external state-changing function of the TMC: valid path (state,
/// money, event) and wrong-role / bad-input reverts with the exact custom error.
contract TasksManagerFuzzTest is Fixture {
    address[] internal workers;

    function setUp() public {
        _deploy();
        for (uint256 i; i < 6; ++i) {
            address w = address(uint160(0xA000 + i));
            _worker(w, 1 << DOMAIN, uint16(4 + 8 * i));
            workers.push(w);
        }
    }

    /// @dev A task of `n` slots allocated: returns its id and the offered workers.
    function _allocated(uint8 n, uint256 reward) internal returns (uint256 id, address[] memory offered) {
        id = _task(n, reward);
        vm.prank(requester);
        tmc.allocateTask(id);
        offered = tmc.offerees(id);
    }

    function _accepted(uint256 reward) internal returns (uint256 id, address w) {
        address[] memory offered;
        (id, offered) = _allocated(1, reward);
        w = offered[0];
        vm.prank(w);
        tmc.acceptOffer(id);
    }

    function _submitted(uint256 reward, string memory cid) internal returns (uint256 id, address w) {
        (id, w) = _accepted(reward);
        _commit(w, cid);
        vm.prank(w);
        tmc.submitOutcome(id, cid);
    }

    // ------------------------------------------------------------------ admin setters

    function testFuzz_setConfig(uint64 w1, uint32 aw, uint32 rw, address caller) public {
        w1 = uint64(_bound(w1, 1, 1e12));
        aw = uint32(_bound(aw, 1, 30 days - 60));
        rw = uint32(_bound(rw, 1, tmc.MAX_REVIEW_WINDOW()));
        vm.expectEmit(address(tmc));
        emit TasksManager.ConfigUpdated(w1, aw, rw);
        vm.prank(admin);
        tmc.setConfig(w1, aw, rw);
        vm.assertEq(tmc.w1(), w1, "w1");
        vm.assertEq(tmc.acceptWindow(), aw, "acceptWindow");
        vm.assertEq(tmc.reviewWindow(), rw, "reviewWindow");
        vm.expectRevert(TasksManager.TasksBadConfig.selector);
        vm.prank(admin);
        tmc.setConfig(0, aw, rw);
        vm.expectRevert(TasksManager.TasksBadConfig.selector);
        vm.prank(admin);
        tmc.setConfig(w1, 30 days, rw); // + minWorkTime > maxDuration
        uint32 tooLong = uint32(_bound(rw, uint256(tmc.MAX_REVIEW_WINDOW()) + 1, type(uint32).max));
        vm.expectRevert(TasksManager.TasksBadConfig.selector);
        vm.prank(admin);
        tmc.setConfig(w1, aw, tooLong); // would hold a worker's pay for an unreviewed outcome
        vm.expectRevert(TasksManager.TasksBadConfig.selector);
        vm.prank(admin);
        tmc.setConfig(w1, aw, 0);
        vm.assume(caller != admin);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotAdmin.selector, caller));
        vm.prank(caller);
        tmc.setConfig(w1, aw, rw);
    }

    function testFuzz_setGpuSeries(uint8 series, bool accepted, address caller) public {
        uint256 before = tmc.acceptedGpus();
        uint256 expect = accepted ? before | (uint256(1) << series) : before & ~(uint256(1) << series);
        vm.expectEmit(address(tmc));
        emit TasksManager.AcceptedGpusUpdated(expect);
        vm.prank(admin);
        tmc.setGpuSeries(series, accepted);
        vm.assertEq(tmc.acceptedGpus(), expect, "mask");
        vm.assume(caller != admin);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotAdmin.selector, caller));
        vm.prank(caller);
        tmc.setGpuSeries(series, !accepted);
    }

    function testFuzz_setTaskLimits(uint32 minWork, uint40 maxDur, address caller) public {
        minWork = uint32(_bound(minWork, 1, 1e8));
        maxDur = uint40(_bound(maxDur, uint256(ACCEPT_WINDOW) + minWork, type(uint32).max));
        vm.expectEmit(address(tmc));
        emit TasksManager.TaskLimitsUpdated(minWork, maxDur);
        vm.prank(admin);
        tmc.setTaskLimits(minWork, maxDur);
        vm.assertEq(tmc.minWorkTime(), minWork, "minWorkTime");
        vm.assertEq(tmc.maxDuration(), maxDur, "maxDuration");
        vm.expectRevert(TasksManager.TasksBadConfig.selector);
        vm.prank(admin);
        tmc.setTaskLimits(0, maxDur);
        vm.expectRevert(TasksManager.TasksBadConfig.selector);
        vm.prank(admin);
        tmc.setTaskLimits(minWork, uint40(uint256(ACCEPT_WINDOW) + minWork - 1));
        vm.assume(caller != admin);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotAdmin.selector, caller));
        vm.prank(caller);
        tmc.setTaskLimits(minWork, maxDur);
    }

    function testFuzz_setMinRewardPerHour(uint256 rate, address caller) public {
        uint256 ok = _bound(rate, 0, type(uint96).max);
        vm.expectEmit(address(tmc));
        emit TasksManager.MinRewardPerHourUpdated(ok);
        vm.prank(admin);
        tmc.setMinRewardPerHour(ok);
        vm.assertEq(tmc.minRewardPerHour(), ok, "rate");
        vm.assertEq(tmc.minRewardForDuration(3600), ok == 0 ? 1 : ok, "one hour");
        vm.expectRevert(TasksManager.TasksBadConfig.selector);
        vm.prank(admin);
        tmc.setMinRewardPerHour(_bound(rate, uint256(type(uint96).max) + 1, type(uint256).max));
        vm.assume(caller != admin);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotAdmin.selector, caller));
        vm.prank(caller);
        tmc.setMinRewardPerHour(ok);
    }

    // ------------------------------------------------------------------ addTask

    function testFuzz_addTask_escrows(uint8 n, uint96 reward, uint40 duration) public {
        uint8 nw = uint8(_bound(n, 1, 16));
        uint256 r = _bound(reward, 1, 1e24);
        uint40 d = uint40(_bound(duration, ACCEPT_WINDOW + 60, 30 days));
        TasksManager.TaskParams memory p = _params(nw);
        p.duration = d;
        uint256 balance = address(tmc).balance;
        vm.expectEmit(address(tmc));
        emit TasksManager.TaskAdded(1, requester, DOMAIN, nw, uint96(r), uint40(block.timestamp) + d, 0, 0, 0, 0, "task");
        vm.prank(requester);
        uint256 id = tmc.addTask{value: r * nw}(p);
        vm.assertEq(id, 1, "first id");
        vm.assertEq(address(tmc).balance - balance, r * nw, "escrow = reward * NW");
        (TasksManager.Task memory t, TasksManager.Reqs memory q) = tmc.getTask(id);
        vm.assertEq(t.requester, requester, "requester");
        vm.assertEq(uint256(t.status), uint256(TasksManager.TaskStatus.Open), "open");
        vm.assertEq(t.numWorkers, nw, "NW");
        vm.assertEq(q.reward, r, "reward");
        vm.assertEq(q.domain, DOMAIN, "domain");
        vm.assertEq(q.reviewEnd, uint256(t.deadline) + REVIEW_WINDOW, "review end fixed at posting");
        vm.assertEq(tmc.domainTasks(DOMAIN).length, 1, "domain list");
    }

    /// @dev domainTasksPage: positions [offset, offset + count) in posting order and the total;
    /// shorter at the end, empty for count 0 or an offset at or past the end.
    function testFuzz_domainTasksPage(uint8 posted, uint256 offset, uint256 count) public {
        uint256 n = _bound(posted, 0, 12);
        for (uint256 i; i < n; ++i) _task(1, 1e9);
        offset = offset % 3 == 0 ? offset : _bound(offset, 0, n + 2);
        count = count % 3 == 0 ? count : _bound(count, 0, n + 2);
        (uint256[] memory page, uint256 total) = tmc.domainTasksPage(DOMAIN, offset, count);
        vm.assertEq(total, n, "total");
        uint256 expected = offset >= n ? 0 : (n - offset < count ? n - offset : count);
        vm.assertEq(page.length, expected, "page length");
        for (uint256 i; i < page.length; ++i) vm.assertEq(page[i], offset + i + 1, "ids in posting order");
        (page, total) = tmc.domainTasksPage(DOMAIN, 0, 0);
        vm.assertEq(page.length + total, n, "count 0: empty page, the total");
        (page,) = tmc.domainTasksPage(DOMAIN, n, 1);
        vm.assertEq(page.length, 0, "offset at the end");
        (page,) = tmc.domainTasksPage(DOMAIN, 0, type(uint256).max);
        vm.assertEq(page.length, n, "count past the end");
        vm.assertEq(tmc.domainTasks(DOMAIN).length, n, "the whole list agrees");
        (page, total) = tmc.domainTasksPage(DOMAIN + 1, 0, 5);
        vm.assertEq(page.length + total, 0, "another domain");
    }

    /// @dev A task's description is at most MAX_DESCRIPTION_BYTES (the gateway's is a CID).
    function testFuzz_addTask_descriptionCap(uint16 extra) public {
        uint256 cap = tmc.MAX_DESCRIPTION_BYTES();
        TasksManager.TaskParams memory p = _params(1);
        p.description = string(new bytes(cap));
        vm.prank(requester);
        tmc.addTask{value: 1e9}(p);
        uint256 len = cap + _bound(extra, 1, 4096);
        p.description = string(new bytes(len));
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksDescriptionTooLong.selector, len, cap));
        vm.prank(requester);
        tmc.addTask{value: 1e9}(p);
    }

    function testFuzz_addTask_rejects(address caller, uint8 n, uint32 threshold, uint40 duration, uint256 extra) public {
        vm.assume(caller != requester);
        vm.deal(caller, 1 ether);
        TasksManager.TaskParams memory p = _params(2);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotRequester.selector, caller));
        vm.prank(caller);
        tmc.addTask{value: 2}(p);

        vm.startPrank(requester);
        p.numWorkers = n > 16 ? n : 0;
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksBadWorkerCount.selector, p.numWorkers));
        tmc.addTask{value: 2}(p);
        p.numWorkers = 2;
        p.domain = uint32(_bound(threshold, 48, type(uint32).max));
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksBadDomain.selector, p.domain));
        tmc.addTask{value: 2}(p);
        p.domain = DOMAIN;
        p.minRating = uint32(_bound(threshold, 1e6 + 1, type(uint32).max));
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksBadThreshold.selector, p.minRating));
        tmc.addTask{value: 2}(p);
        p.minRating = 0;
        p.minReputation = p.minRating = 0;
        uint256 shortest = ACCEPT_WINDOW + 60;
        p.duration = duration >= shortest && duration <= 30 days ? 0 : duration;
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksBadDuration.selector, p.duration, shortest, 30 days));
        tmc.addTask{value: 2}(p);
        p.duration = DURATION;
        uint256 value = 2 * 5 + 1 + 2 * _bound(extra, 0, 1e20); // odd: not a multiple of NW
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksBadPayment.selector, value, 2));
        tmc.addTask{value: value}(p);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksRewardBelowMinimum.selector, 0, 1));
        tmc.addTask{value: 0}(p);
        vm.stopPrank();
        vm.assertEq(tmc.taskCount(), 0, "nothing created");
        vm.assertEq(address(tmc).balance, 0, "nothing escrowed");
    }

    function testFuzz_addTask_minimumReward(uint96 rate, uint40 duration) public {
        uint256 r = _bound(rate, 1, 1e20);
        uint40 d = uint40(_bound(duration, ACCEPT_WINDOW + 60, 30 days));
        vm.prank(admin);
        tmc.setMinRewardPerHour(r);
        uint256 minimum = (r * d + 3599) / 3600;
        TasksManager.TaskParams memory p = _params(1);
        p.duration = d;
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksRewardBelowMinimum.selector, minimum - 1, minimum));
        vm.prank(requester);
        tmc.addTask{value: minimum - 1}(p);
        vm.prank(requester);
        tmc.addTask{value: minimum}(p);
    }

    // ------------------------------------------------------------------ allocateTask

    function testFuzz_allocateTask(uint8 n, bool byAdmin) public {
        uint8 nw = uint8(_bound(n, 1, 8));
        uint256 id = _task(nw, 1e9);
        vm.prank(byAdmin ? admin : requester);
        uint256 offered = tmc.allocateTask(id);
        uint256 expected = nw < workers.length ? nw : workers.length;
        vm.assertEq(offered, expected, "offers = min(NW, eligible)");
        address[] memory list = tmc.offerees(id);
        // best QoS first: more cores -> higher CC (Eq. 20); all other terms equal (new workers)
        for (uint256 i; i < list.length; ++i) {
            vm.assertEq(list[i], workers[workers.length - 1 - i], "greedy order");
            // an offer counts once accepted or at the task's end, not when made
            vm.assertEq(umc.counters(list[i], DOMAIN, 0).assigned, 0, "nothing counted yet");
            TasksManager.Offer memory o = tmc.getOffer(id, list[i]);
            vm.assertEq(uint256(o.state), uint256(TasksManager.OfferState.Offered), "offered");
            vm.assertEq(o.expiry, block.timestamp + ACCEPT_WINDOW, "expiry");
        }
        if (offered == nw) {
            vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNoOpenSlot.selector, id));
            vm.prank(requester);
            tmc.allocateTask(id);
        }
    }

    function testFuzz_allocateTask_rejects(address caller, uint256 unknown, uint256 late) public {
        vm.assume(caller != requester && caller != admin);
        uint256 id = _task(1, 1e9);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotTaskRequester.selector, id, caller));
        vm.prank(caller);
        tmc.allocateTask(id);
        uint256 other = _bound(unknown, 2, type(uint256).max);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksUnknownTask.selector, other));
        vm.prank(caller);
        tmc.allocateTask(other);
        (TasksManager.Task memory t,) = tmc.getTask(id);
        vm.warp(_bound(late, t.deadline - ACCEPT_WINDOW - 60 + 1, t.deadline));
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksTooLateToOffer.selector, id, t.deadline));
        vm.prank(requester);
        tmc.allocateTask(id);
        vm.warp(uint256(t.deadline) + 1);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksDeadlinePassed.selector, id, t.deadline));
        vm.prank(requester);
        tmc.allocateTask(id);
    }

    // ------------------------------------------------------------------ offers

    function testFuzz_acceptOffer(uint32 after_, address stranger_) public {
        (uint256 id, address[] memory offered) = _allocated(2, 1e9);
        vm.assume(stranger_ != offered[0] && stranger_ != offered[1]);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotOfferedWorker.selector, id, stranger_));
        vm.prank(stranger_);
        tmc.acceptOffer(id);
        uint256 t = _bound(after_, 0, ACCEPT_WINDOW);
        vm.warp(block.timestamp + t);
        vm.expectEmit(address(tmc));
        emit TasksManager.OfferAccepted(id, offered[0]);
        vm.prank(offered[0]);
        tmc.acceptOffer(id);
        (TasksManager.Task memory task,) = tmc.getTask(id);
        vm.assertEq(task.filled, 1, "filled");
        vm.assertEq(task.liveOffers, 1, "live");
        vm.assertEq(umc.counters(offered[0], DOMAIN, 0).accepted, 1, "accepted counted");
        vm.assertEq(umc.counters(offered[0], DOMAIN, 0).assigned, 1, "assigned with it");
        vm.assertEq(umc.counters(offered[1], DOMAIN, 0).assigned, 0, "live offer not counted");
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotOfferedWorker.selector, id, offered[0]));
        vm.prank(offered[0]);
        tmc.acceptOffer(id);
        vm.warp(block.timestamp + ACCEPT_WINDOW - t + 1);
        TasksManager.Offer memory o = tmc.getOffer(id, offered[1]);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksOfferExpired.selector, id, offered[1], o.expiry));
        vm.prank(offered[1]);
        tmc.acceptOffer(id);
    }

    function testFuzz_declineOffer_nextBest(address stranger_) public {
        (uint256 id, address[] memory offered) = _allocated(1, 1e9);
        vm.assume(stranger_ != offered[0]);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotOfferedWorker.selector, id, stranger_));
        vm.prank(stranger_);
        tmc.declineOffer(id);
        vm.expectEmit(address(tmc));
        emit TasksManager.OfferDeclined(id, offered[0]);
        vm.prank(offered[0]);
        tmc.declineOffer(id);
        vm.prank(requester);
        tmc.allocateTask(id);
        address[] memory list = tmc.offerees(id);
        vm.assertEq(list.length, 2, "re-offered");
        vm.assertEq(list[1], workers[workers.length - 2], "next best, never the decliner");
    }

    function testFuzz_abandonOffer(address stranger_) public {
        (uint256 id, address w) = _accepted(1e9);
        vm.assume(stranger_ != w);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotAssignedWorker.selector, id, stranger_));
        vm.prank(stranger_);
        tmc.abandonOffer(id);
        vm.expectEmit(address(tmc));
        emit TasksManager.OfferFailed(id, w);
        vm.prank(w);
        tmc.abandonOffer(id);
        (TasksManager.Task memory t,) = tmc.getTask(id);
        vm.assertEq(t.filled, 0, "slot open again");
        vm.assertEq(uint256(tmc.getOffer(id, w).state), uint256(TasksManager.OfferState.Failed), "failed");
    }

    // ------------------------------------------------------------------ submitOutcome

    function testFuzz_submitOutcome(string calldata cidSeed, address stranger_) public {
        string memory cid = cidFor(bytes(cidSeed));
        vm.assume(bytes(cid).length != 0);
        (uint256 id, address w) = _accepted(1e9);
        vm.assume(stranger_ != w);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotAssignedWorker.selector, id, stranger_));
        vm.prank(stranger_);
        tmc.submitOutcome(id, cid);
        vm.expectRevert(TasksManager.TasksEmptyCid.selector);
        vm.prank(w);
        tmc.submitOutcome(id, "");
        _commit(w, cid);
        vm.expectEmit(address(tmc));
        emit TasksManager.OutcomeSubmitted(id, w, cid);
        vm.prank(w);
        tmc.submitOutcome(id, cid);
        (address who, uint256 task,) = tmc.outcomeOf(keccak256(bytes(cid)));
        vm.assertEq(who, w, "provenance worker");
        vm.assertEq(task, id, "provenance task");
        vm.assertEq(umc.counters(w, DOMAIN, 0).completed, 0, "completed only once accepted");
        // the same CID for another slot is refused
        (uint256 id2, address w2) = _accepted(1e9);
        _commit(w2, cid);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksDuplicateOutcome.selector, id, w));
        vm.prank(w2);
        tmc.submitOutcome(id2, cid);
        // ... and so is the same CID re-encoded (multibase B, upper-case base32): one text per CID
        bytes memory upper = bytes(cid);
        for (uint256 i; i < upper.length; ++i) {
            if (upper[i] >= "a" && upper[i] <= "z") upper[i] = bytes1(uint8(upper[i]) - 32);
        }
        _commit(w2, string(upper));
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksCidNotCanonical.selector, string(upper)));
        vm.prank(w2);
        tmc.submitOutcome(id2, string(upper));
    }

    /// @dev One spelling per CID within base32 too: the CID of some bytes is accepted, and the
    /// three texts that differ only in the 2 unused low bits of its last character (which a
    /// decoder ignores, so the same CID) are refused, as are body lengths no bytes encode to.
    function testFuzz_submitOutcome_oneSpellingPerCid(uint8 pick) public {
        string memory cid = "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yeq";
        string[3] memory variants = [
            "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yer",
            "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yes",
            "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yet"
        ];
        string[3] memory badLengths = ["ba", "baaa", "baaaaaa"]; // body % 8 = 1, 3, 6
        (uint256 id, address w) = _accepted(1e9);
        string memory bad = pick % 2 == 0 ? variants[pick % 3] : badLengths[pick % 3];
        _commit(w, bad); // committed: only the spelling refuses it
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksCidNotCanonical.selector, bad));
        vm.prank(w);
        tmc.submitOutcome(id, bad);
        for (uint256 i; i < 3; ++i) {
            vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksCidNotCanonical.selector, variants[i]));
            vm.prank(w);
            tmc.submitOutcome(id, variants[i]);
            vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksCidNotCanonical.selector, badLengths[i]));
            vm.prank(w);
            tmc.submitOutcome(id, badLengths[i]);
        }
        _commit(w, cid);
        vm.prank(w);
        tmc.submitOutcome(id, cid);
        (address who,,) = tmc.outcomeOf(keccak256(bytes(cid)));
        vm.assertEq(who, w, "the one spelling recorded");
    }

    function testFuzz_submitOutcome_listedModelRefused(string calldata cidSeed) public {
        string memory cid = cidFor(bytes(cidSeed));
        vm.assume(bytes(cid).length != 0);
        // a worker lists its own upload; another hands the same CID in as its task's outcome
        address owner_ = workers[5];
        uint32[] memory env = new uint32[](2);
        (env[0], env[1]) = (3, 3);
        _commit(owner_, cid);
        vm.prank(owner_);
        uint256 modelId = mmc.addModel(cid, "mine", DOMAIN, env);
        (uint256 id, address w) = _accepted(1e9);
        _commit(w, cid);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksOutcomeIsListedModel.selector, modelId));
        vm.prank(w);
        tmc.submitOutcome(id, cid);
        (address who,,) = tmc.outcomeOf(keccak256(bytes(cid)));
        vm.assertEq(who, address(0), "no outcome recorded");
    }

    // ------------------------------------------------------------------ commit-reveal of CIDs

    function testFuzz_commitCid(bytes32 commitment, address stranger_) public {
        address w = workers[0];
        vm.assume(umc.workerId(stranger_) == 0);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotWorker.selector, stranger_));
        vm.prank(stranger_);
        tmc.commitCid(commitment);
        vm.expectEmit(address(tmc));
        emit TasksManager.CidCommitted(w, commitment);
        vm.prank(w);
        tmc.commitCid(commitment);
        uint256 first = vm.getBlockNumber(); // block.number is constant to the optimizer
        vm.assertEq(tmc.cidCommits(commitment), first, "block recorded");
        vm.assertFalse(tmc.committedBefore(commitment), "not before its own block");
        vm.roll(first + 5);
        vm.recordLogs();
        vm.prank(w);
        tmc.commitCid(commitment); // a retry keeps the first block and says nothing
        vm.assertEq(vm.getRecordedLogs().length, 0, "no event for a repeated commitment");
        vm.assertEq(tmc.cidCommits(commitment), first, "first block kept");
        vm.assertTrue(tmc.committedBefore(commitment), "committed before this block");
    }

    /// @dev A worker keeps its last MAX_LIVE_COMMITMENTS commitments: each newer one evicts
    /// the oldest still unspent ({CidCommitmentEvicted}), never a commitment another worker
    /// made first, and a repeat of a live one changes nothing (docs/chain.md, "Held-out pass
    /// of 2026-12-05, second").
    function testFuzz_commitCid_ring(uint8 extra, bytes32 seed) public {
        address w = workers[0];
        uint256 ring = tmc.MAX_LIVE_COMMITMENTS();
        bytes32 theirs = keccak256(abi.encode(seed, "theirs"));
        vm.prank(workers[1]);
        tmc.commitCid(theirs);
        vm.recordLogs();
        vm.prank(w);
        tmc.commitCid(theirs); // live already: a no-op, not in w's ring
        vm.assertEq(vm.getRecordedLogs().length, 0, "no event for a live commitment");
        uint256 n = ring + _bound(extra, 1, 3 * ring);
        bytes32[] memory hs = new bytes32[](n);
        for (uint256 i; i < n; ++i) {
            hs[i] = keccak256(abi.encode(seed, i));
            if (i >= ring) {
                vm.expectEmit(address(tmc));
                emit TasksManager.CidCommitmentEvicted(w, hs[i - ring]);
            }
            vm.expectEmit(address(tmc));
            emit TasksManager.CidCommitted(w, hs[i]);
            vm.prank(w);
            tmc.commitCid(hs[i]);
            vm.roll(vm.getBlockNumber() + 1);
        }
        for (uint256 i; i < n; ++i) {
            vm.assertEq(tmc.cidCommits(hs[i]) != 0, i + ring >= n, "exactly the last MAX_LIVE_COMMITMENTS live");
        }
        vm.assertTrue(tmc.committedBefore(theirs), "another worker's commitment is never evicted by w");
    }

    /// @dev Who may write a commitment slot: not a stranger's fresh registration (Pending,
    /// never approved), nor an approved worker sent back to Pending that never took a task;
    /// an Idle worker may; and a worker holding an accepted job still may after going back to
    /// Pending (capabilities changed) or being removed, so it can submit that job.
    function testFuzz_commitCid_whoMay(bytes32 commitment, bool removeIt) public {
        address pending = _actor("pending");
        vm.prank(pending);
        umc.addWorker(1 << DOMAIN, 64, 64, 1); // approval is on: Pending
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotWorker.selector, pending));
        vm.prank(pending);
        tmc.commitCid(commitment);
        address idle = workers[0];
        vm.prank(idle);
        umc.updateCapabilities(5, 32, 1); // approved, never took a task: Pending again
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotWorker.selector, idle));
        vm.prank(idle);
        tmc.commitCid(commitment);
        vm.prank(admin);
        umc.approveWorker(idle);
        vm.prank(idle);
        umc.updateStatus(UsersManager.Status.Idle);
        vm.prank(idle);
        tmc.commitCid(commitment); // Idle: approved
        // an accepted job, then a change of capabilities (or removal): it can still submit
        (uint256 id, address w) = _accepted(1e9);
        vm.prank(w);
        if (removeIt) umc.removeWorker(w);
        else umc.updateCapabilities(99, 99, 1);
        string memory cid = cidFor("pending again");
        _commit(w, cid);
        vm.prank(w);
        tmc.submitOutcome(id, cid);
        (address who,,) = tmc.outcomeOf(keccak256(bytes(cid)));
        vm.assertEq(who, w, "submitted");
    }

    function testFuzz_submitOutcome_needsEarlierCommit(string calldata cidSeed) public {
        string memory cid = cidFor(bytes(cidSeed));
        vm.assume(bytes(cid).length != 0);
        (uint256 id, address w) = _accepted(1e9);
        bytes32 commitment = keccak256(abi.encodePacked(cid, w));
        vm.assertEq(tmc.cidCommitment(cid, w), commitment, "commitment formula");
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksCidNotCommitted.selector, commitment));
        vm.prank(w);
        tmc.submitOutcome(id, cid); // never committed
        address other = workers[1] == w ? workers[2] : workers[1];
        _commit(other, cid);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksCidNotCommitted.selector, commitment));
        vm.prank(w);
        tmc.submitOutcome(id, cid); // another's commitment of the same CID is not w's
        vm.prank(w);
        tmc.commitCid(commitment);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksCidNotCommitted.selector, commitment));
        vm.prank(w);
        tmc.submitOutcome(id, cid); // committed in this very block: not yet
        vm.roll(vm.getBlockNumber() + 1);
        vm.prank(w);
        tmc.submitOutcome(id, cid);
        vm.assertEq(tmc.cidCommits(commitment), 0, "commitment spent");
    }

    /// @dev The attack commit-reveal closes: a worker's CID shows in its pending submitOutcome;
    /// a copier with an accepted offer of its own commits it at once and tries to hand it in
    /// first. Its reveal cannot come before the next block, by which the producer's is in.
    function testFuzz_frontRunningOutcomeFails(string calldata cidSeed) public {
        string memory cid = cidFor(bytes(cidSeed));
        vm.assume(bytes(cid).length != 0);
        (uint256 id, address[] memory ws) = _twoAccepted();
        _commit(ws[0], cid); // the producer commits before it uploads
        // the copier sees cid in the producer's pending reveal and races it in this block
        vm.prank(ws[1]);
        tmc.commitCid(keccak256(abi.encodePacked(cid, ws[1])));
        vm.expectRevert(
            abi.encodeWithSelector(TasksManager.TasksCidNotCommitted.selector, keccak256(abi.encodePacked(cid, ws[1])))
        );
        vm.prank(ws[1]);
        tmc.submitOutcome(id, cid);
        vm.prank(ws[0]);
        tmc.submitOutcome(id, cid);
        vm.roll(vm.getBlockNumber() + 1); // next block: the copier is refused by the outcome record
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksDuplicateOutcome.selector, id, ws[0]));
        vm.prank(ws[1]);
        tmc.submitOutcome(id, cid);
        (address who,,) = tmc.outcomeOf(keccak256(bytes(cid)));
        vm.assertEq(who, ws[0], "the producer's outcome");
    }

    /// @dev One task, two workers who accepted it.
    function _twoAccepted() internal returns (uint256 id, address[] memory ws) {
        (id, ws) = _allocated(2, 1e9);
        for (uint256 i; i < 2; ++i) {
            vm.prank(ws[i]);
            tmc.acceptOffer(id);
        }
    }

    function testFuzz_setModels(address caller, address other) public {
        vm.assume(caller != admin && other != address(0));
        vm.assertEq(address(tmc.models()), address(mmc), "set at deployment");
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotAdmin.selector, caller));
        vm.prank(caller);
        tmc.setModels(IModelsListing(other));
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksModelsAlreadySet.selector, address(mmc)));
        vm.prank(admin);
        tmc.setModels(IModelsListing(other));
    }

    // ------------------------------------------------------------------ reviewOutcome

    function testFuzz_reviewOutcome(uint8 review, bool accepted, address stranger_) public {
        uint256 reward = 1e9;
        (uint256 id, address w) = _submitted(reward, cidFor("review"));
        vm.assume(stranger_ != requester);
        uint8 r = uint8(_bound(review, 0, 5));
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotTaskRequester.selector, id, stranger_));
        vm.prank(stranger_);
        tmc.reviewOutcome(id, w, r, accepted);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksBadReview.selector, uint8(_bound(review, 6, 255))));
        vm.prank(requester);
        tmc.reviewOutcome(id, w, uint8(_bound(review, 6, 255)), accepted);
        vm.expectEmit(address(tmc));
        emit TasksManager.OutcomeReviewed(id, w, r, accepted);
        vm.prank(requester);
        tmc.reviewOutcome(id, w, r, accepted);
        vm.assertEq(tmc.credits(accepted ? w : requester), reward, "slot paid or refunded");
        vm.assertEq(tmc.credits(accepted ? requester : w), 0, "only once");
        (TasksManager.Task memory t,) = tmc.getTask(id);
        vm.assertEq(uint256(t.status), uint256(TasksManager.TaskStatus.Completed), "completed");
        vm.assertEq(umc.counters(w, DOMAIN, 0).ratingSum, r, "rating");
        vm.assertEq(umc.counters(w, DOMAIN, 0).ratingCount, 1, "rated either way");
        // a rejected outcome is no completed task (E of Eq. 18, N of Eq. 16)
        vm.assertEq(umc.counters(w, DOMAIN, 0).completed, accepted ? 1 : 0, "completed only if accepted");
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotSubmitted.selector, id, w));
        vm.prank(requester);
        tmc.reviewOutcome(id, w, r, accepted);
    }

    function testFuzz_reviewOutcome_windowCloses(uint32 late) public {
        (uint256 id, address w) = _submitted(1e9, cidFor("late"));
        (TasksManager.Task memory t,) = tmc.getTask(id);
        uint256 end = uint256(t.deadline) + REVIEW_WINDOW;
        vm.warp(_bound(late, end + 1, end + 1e9));
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksReviewWindowClosed.selector, id, end));
        vm.prank(requester);
        tmc.reviewOutcome(id, w, 0, false);
        // the outcome is the worker's: paid at close, with no review (not a review of 0)
        vm.expectEmit(address(tmc));
        emit TasksManager.OutcomePaidUnreviewed(id, w);
        vm.prank(w);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Closed);
        vm.assertEq(tmc.credits(w), 1e9, "paid unreviewed");
        vm.assertEq(umc.counters(w, DOMAIN, 0).ratingCount, 0, "no rating");
        vm.assertEq(umc.counters(w, DOMAIN, 0).completed, 1, "completed");
    }

    /// @dev The review end is the task's, fixed when it was posted: an admin lowering the
    /// window cannot let an offeree close early and be paid an outcome the requester had not
    /// reviewed yet; raising it cannot hold the worker's pay past the end it was promised.
    function testFuzz_reviewWindowFixedAtPosting(uint32 newWindow, bool lower) public {
        (uint256 id, address w) = _submitted(1e9, cidFor("window"));
        (TasksManager.Task memory t, TasksManager.Reqs memory q) = tmc.getTask(id);
        uint256 end = uint256(t.deadline) + REVIEW_WINDOW;
        vm.assertEq(q.reviewEnd, end, "recorded");
        uint32 rw = lower
            ? uint32(_bound(newWindow, 1, REVIEW_WINDOW - 1))
            : uint32(_bound(newWindow, REVIEW_WINDOW + 1, tmc.MAX_REVIEW_WINDOW()));
        vm.prank(admin);
        tmc.setConfig(W1, ACCEPT_WINDOW, rw);
        vm.warp(end); // past deadline + the new (lower) window, at the task's own end
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksReviewWindowOpen.selector, id, end));
        vm.prank(w);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Closed);
        if (lower) {
            vm.prank(requester); // still inside the task's window
            tmc.reviewOutcome(id, w, 1, false);
            vm.assertEq(tmc.credits(requester), 1e9, "the requester's review stands");
        } else {
            vm.warp(end + 1);
            vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksReviewWindowClosed.selector, id, end));
            vm.prank(requester);
            tmc.reviewOutcome(id, w, 0, false);
            vm.prank(w);
            tmc.updateTaskStatus(id, TasksManager.TaskStatus.Closed);
            vm.assertEq(tmc.credits(w), 1e9, "paid at the end it was promised");
        }
        // a task posted now gets the new window
        (, TasksManager.Reqs memory later) = tmc.getTask(_task(1, 1e9));
        (TasksManager.Task memory lt,) = tmc.getTask(tmc.taskCount());
        vm.assertEq(later.reviewEnd, uint256(lt.deadline) + rw, "new tasks, new window");
    }

    // ------------------------------------------------------------------ updateTaskStatus

    function testFuzz_cancel_refundsAll(uint8 n, uint96 reward, address stranger_) public {
        uint8 nw = uint8(_bound(n, 1, 16));
        uint256 r = _bound(reward, 1, 1e24);
        uint256 id = _task(nw, r);
        vm.assume(stranger_ != requester);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotTaskRequester.selector, id, stranger_));
        vm.prank(stranger_);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Cancelled);
        vm.expectEmit(address(tmc));
        emit TasksManager.PaymentCredited(requester, id, r * nw);
        vm.prank(requester);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Cancelled);
        vm.assertEq(tmc.credits(requester), r * nw, "full refund");
        vm.expectRevert(
            abi.encodeWithSelector(TasksManager.TasksNotOpen.selector, id, TasksManager.TaskStatus.Cancelled)
        );
        vm.prank(requester);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Cancelled);
    }

    function testFuzz_cancel_rejects(uint8 raw) public {
        (uint256 id,) = _allocated(2, 1e9);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksHasLiveOffers.selector, id));
        vm.prank(requester);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Cancelled);
        address w = tmc.offerees(id)[0];
        vm.prank(w);
        tmc.acceptOffer(id);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksHasAcceptedWorkers.selector, id));
        vm.prank(requester);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Cancelled);
        uint8 s = uint8(_bound(raw, 0, 2)); // None, Open, Completed: no caller may set them
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksBadStatus.selector, s));
        vm.prank(requester);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus(s));
    }

    function testFuzz_cancel_expiresStaleOffers(uint8 n, uint32 late) public {
        uint8 nw = uint8(_bound(n, 1, 3));
        (uint256 id, address[] memory offered) = _allocated(nw, 1e9);
        vm.warp(block.timestamp + ACCEPT_WINDOW + _bound(late, 1, 30)); // before the deadline
        for (uint256 i; i < offered.length; ++i) {
            vm.expectEmit(address(tmc));
            emit TasksManager.OfferExpired(id, offered[i]);
        }
        vm.expectEmit(address(tmc));
        emit TasksManager.TaskStatusUpdated(id, TasksManager.TaskStatus.Cancelled);
        vm.prank(requester);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Cancelled);
        (TasksManager.Task memory t,) = tmc.getTask(id);
        vm.assertEq(t.liveOffers, 0, "no live offer on a cancelled task");
        for (uint256 i; i < offered.length; ++i) {
            vm.assertEq(
                uint256(tmc.getOffer(id, offered[i]).state), uint256(TasksManager.OfferState.Expired), "expired"
            );
            vm.assertEq(umc.counters(offered[i], DOMAIN, 0).assigned, 0, "never counted");
        }
    }

    function testFuzz_close_settles(uint32 late, address stranger_) public {
        uint256 reward = 1e9;
        (uint256 id, address[] memory offered) = _allocated(3, reward);
        vm.prank(offered[0]);
        tmc.acceptOffer(id);
        _commit(offered[0], cidFor("close"));
        vm.prank(offered[0]);
        tmc.submitOutcome(id, cidFor("close"));
        vm.prank(offered[1]);
        tmc.acceptOffer(id); // accepted, never submits -> Failed at close
        (TasksManager.Task memory t,) = tmc.getTask(id);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksDeadlineNotPassed.selector, id, t.deadline));
        vm.prank(requester);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Closed);
        vm.assume(stranger_ != requester && stranger_ != admin);
        vm.assume(stranger_ != offered[0] && stranger_ != offered[1] && stranger_ != offered[2]);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotParticipant.selector, id, stranger_));
        vm.prank(stranger_);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Closed);
        uint256 end = uint256(t.deadline) + REVIEW_WINDOW;
        vm.warp(_bound(late, t.deadline + 1, end));
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksReviewWindowOpen.selector, id, end));
        vm.prank(requester);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Closed);
        vm.warp(end + 1);
        vm.expectEmit(address(tmc));
        emit TasksManager.TaskStatusUpdated(id, TasksManager.TaskStatus.Closed);
        vm.prank(offered[2]);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Closed);
        vm.assertEq(tmc.credits(offered[0]), reward, "unreviewed outcome paid");
        vm.assertEq(tmc.credits(requester), 2 * reward, "other slots refunded");
        vm.assertEq(uint256(tmc.getOffer(id, offered[1]).state), uint256(TasksManager.OfferState.Failed), "failed");
        vm.assertEq(uint256(tmc.getOffer(id, offered[2]).state), uint256(TasksManager.OfferState.Expired), "expired");
        // paid unreviewed: completed, not rated; held to the deadline: rated 0, not completed;
        // the expired offer of a task that found workers still counts as assigned
        _assertCounters(offered[0], 1, 1, 1, 0);
        _assertCounters(offered[1], 1, 1, 0, 1);
        _assertCounters(offered[2], 1, 0, 0, 0);
        vm.assertEq(umc.counters(offered[1], DOMAIN, 0).ratingSum, 0, "rated 0");
    }

    function _assertCounters(address w, uint256 assigned, uint256 accepted, uint256 completed, uint256 rated)
        internal
        view
    {
        vm.assertEq(umc.counters(w, DOMAIN, 0).assigned, assigned, "assigned");
        vm.assertEq(umc.counters(w, DOMAIN, 0).accepted, accepted, "accepted");
        vm.assertEq(umc.counters(w, DOMAIN, 0).completed, completed, "completed");
        vm.assertEq(umc.counters(w, DOMAIN, 0).ratingCount, rated, "rating count");
    }

    /// @dev The first audit's attack: a requester makes offers only to have them refused
    /// (declined, or left to expire), then cancels or lets the tasks run out and closes them.
    /// With no worker holding a slot at the end, no offer ever counts: the victims' counters,
    /// hence their reputations, never move, whichever way each task ends.
    function testFuzz_offersOfTasksNobodyHeldNeverCount(uint8 n, uint256 seed) public {
        uint256 tasks = _bound(n, 1, 6);
        uint256[] memory ids = new uint256[](tasks);
        for (uint256 i; i < tasks; ++i) {
            address[] memory offered;
            (ids[i], offered) = _allocated(uint8(1 + (seed >> i) % 3), 1e9);
            if ((seed >> (8 + i)) & 1 == 1) {
                for (uint256 j; j < offered.length; ++j) {
                    vm.prank(offered[j]);
                    tmc.declineOffer(ids[i]);
                }
            }
        }
        for (uint256 k; k < workers.length; ++k) _assertCounters(workers[k], 0, 0, 0, 0);
        vm.warp(block.timestamp + ACCEPT_WINDOW + 1);
        for (uint256 i; i < tasks; ++i) {
            uint256 how = (seed >> (16 + 2 * i)) % 3;
            vm.startPrank(requester);
            if (how == 0) tmc.updateTaskStatus(ids[i], TasksManager.TaskStatus.Cancelled);
            else if (how == 1) tmc.cancelOpenSlots(ids[i]);
            vm.stopPrank();
        }
        (TasksManager.Task memory last,) = tmc.getTask(ids[tasks - 1]);
        vm.warp(uint256(last.deadline) + 1);
        for (uint256 i; i < tasks; ++i) {
            (TasksManager.Task memory t,) = tmc.getTask(ids[i]);
            vm.assertEq(t.filled, 0, "nobody held a slot");
            if (t.status != TasksManager.TaskStatus.Open) continue;
            vm.prank(requester);
            tmc.updateTaskStatus(ids[i], TasksManager.TaskStatus.Closed);
        }
        for (uint256 k; k < workers.length; ++k) _assertCounters(workers[k], 0, 0, 0, 0);
        vm.assertTrue(tmc.credits(requester) > 0, "escrow refunded");
    }

    /// @dev The decoy (audit of the decoy offers): a long task only the victim qualifies for,
    /// declined, never cancelled. While the task runs the decline costs the victim nothing: its
    /// reputation stays at a new worker's 0.5, so a task asking for minReputation 0.5 still
    /// offers it work; and at the task's end, with no slot held, it never counts.
    function testFuzz_decoyOfferOfOpenTaskDoesNotCount(uint32 wait, bool closeIt) public {
        address victim = workers[workers.length - 1];
        TasksManager.TaskParams memory p = _params(1);
        p.minCpuCores = 44; // only the victim (44 cores) qualifies
        p.duration = 30 days;
        vm.prank(requester);
        uint256 decoy = tmc.addTask{value: 1e9}(p);
        vm.prank(requester);
        tmc.allocateTask(decoy);
        vm.assertEq(tmc.offerees(decoy)[0], victim, "only the victim offered");
        vm.prank(victim);
        tmc.declineOffer(decoy);
        (TasksManager.Task memory t,) = tmc.getTask(decoy);
        vm.warp(_bound(wait, block.timestamp, t.deadline - ACCEPT_WINDOW - 60));
        _assertCounters(victim, 0, 0, 0, 0);
        p.minCpuCores = 44;
        p.minReputation = 500_000;
        p.duration = 1 days;
        vm.prank(requester);
        uint256 honest = tmc.addTask{value: 1e9}(p);
        vm.prank(requester);
        vm.assertEq(tmc.allocateTask(honest), 1, "the victim still qualifies");
        vm.assertEq(tmc.offerees(honest)[0], victim, "offered to the victim");
        vm.warp(uint256(t.deadline) + 1);
        if (closeIt) {
            vm.prank(requester);
            tmc.updateTaskStatus(decoy, TasksManager.TaskStatus.Closed);
        }
        _assertCounters(victim, 0, 0, 0, 0);
    }

    /// @dev The accomplice (second finding): a worker accepts a slot and gives it back at once
    /// ({abandonOffer}, never rated); the requester then cancels. Nobody holds a slot at the
    /// end, so the victim's declined offer never counts; the accomplice keeps its own count
    /// (assigned and accepted, not completed).
    function testFuzz_acceptThenAbandonDoesNotCountOthers(bool viaSlots) public {
        (uint256 id, address[] memory offered) = _allocated(2, 1e9);
        vm.prank(offered[1]);
        tmc.declineOffer(id);
        vm.prank(offered[0]);
        tmc.acceptOffer(id);
        vm.prank(offered[0]);
        tmc.abandonOffer(id);
        vm.prank(requester);
        if (viaSlots) tmc.cancelOpenSlots(id);
        else tmc.updateTaskStatus(id, TasksManager.TaskStatus.Cancelled);
        (TasksManager.Task memory t,) = tmc.getTask(id);
        vm.assertEq(uint256(t.status), uint256(TasksManager.TaskStatus.Cancelled), "cancelled");
        _assertCounters(offered[0], 1, 1, 0, 0); // gave it back: no rating, not completed
        _assertCounters(offered[1], 0, 0, 0, 0); // declined a task nobody held at its end
    }

    /// @dev A task some worker held to its end counts the offers it made that were never
    /// accepted (declined, or expired) in A of Eq. 17, whichever way it ends: its last review
    /// (Completed), {cancelOpenSlots} with every slot left reviewed (Completed), or the close.
    /// Nothing counts before the end.
    function testFuzz_offersOfHeldTasksCountAtTheEnd(uint8 how, bool accept) public {
        uint8 end = uint8(_bound(how, 0, 2));
        (uint256 id, address[] memory offered) = _allocated(3, 1e9);
        vm.prank(offered[0]);
        tmc.acceptOffer(id);
        vm.prank(offered[1]);
        tmc.declineOffer(id); // offered[2] lets its offer expire
        _commit(offered[0], cidFor("held"));
        vm.prank(offered[0]);
        tmc.submitOutcome(id, cidFor("held"));
        vm.warp(block.timestamp + ACCEPT_WINDOW + 1);
        if (end == 0) {
            // the requester gives up the two open slots first: one slot left, then reviewed
            vm.prank(requester);
            tmc.cancelOpenSlots(id);
        }
        _assertCounters(offered[1], 0, 0, 0, 0);
        _assertCounters(offered[2], 0, 0, 0, 0);
        if (end == 0 || end == 1) {
            vm.prank(requester);
            tmc.reviewOutcome(id, offered[0], 5, accept);
            if (end == 1) {
                vm.prank(requester); // the two open slots go: only the reviewed one is left
                tmc.cancelOpenSlots(id);
            }
            (TasksManager.Task memory t,) = tmc.getTask(id);
            vm.assertEq(uint256(t.status), uint256(TasksManager.TaskStatus.Completed), "completed");
        } else {
            (TasksManager.Task memory t, TasksManager.Reqs memory q) = tmc.getTask(id);
            vm.warp(uint256(q.reviewEnd) + 1);
            vm.prank(requester);
            tmc.updateTaskStatus(id, TasksManager.TaskStatus.Closed);
            vm.assertEq(t.filled, 1, "held at the end");
        }
        _assertCounters(offered[1], 1, 0, 0, 0); // declined a task that found a worker
        _assertCounters(offered[2], 1, 0, 0, 0); // let it expire
        vm.assertEq(umc.counters(offered[0], DOMAIN, 0).assigned, 1, "counted once, at accept");
        vm.assertEq(umc.counters(offered[0], DOMAIN, 0).accepted, 1, "accepted");
    }

    // ------------------------------------------------------------------ cancelOpenSlots

    function testFuzz_cancelOpenSlots(uint8 n, address stranger_) public {
        uint8 nw = uint8(_bound(n, 2, 5));
        uint256 reward = 1e9;
        (uint256 id, address[] memory offered) = _allocated(nw, reward);
        vm.assume(stranger_ != requester);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotTaskRequester.selector, id, stranger_));
        vm.prank(stranger_);
        tmc.cancelOpenSlots(id);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNoOpenSlot.selector, id));
        vm.prank(requester);
        tmc.cancelOpenSlots(id); // every slot inside a live offer
        vm.prank(offered[0]);
        tmc.acceptOffer(id);
        vm.warp(block.timestamp + ACCEPT_WINDOW + 1); // the other offers expire
        vm.expectEmit(address(tmc));
        emit TasksManager.SlotsCancelled(id, nw - 1, 1);
        vm.prank(requester);
        uint256 cancelled = tmc.cancelOpenSlots(id);
        vm.assertEq(cancelled, nw - 1, "cancelled");
        vm.assertEq(tmc.credits(requester), (nw - 1) * reward, "refund");
        (TasksManager.Task memory t,) = tmc.getTask(id);
        vm.assertEq(t.numWorkers, 1, "one slot left");
    }

    // ------------------------------------------------------------------ withdraw

    function testFuzz_withdraw(uint96 reward, address stranger_) public {
        uint256 r = _bound(reward, 1, 1e24);
        uint256 id = _task(1, r);
        vm.prank(requester);
        tmc.updateTaskStatus(id, TasksManager.TaskStatus.Cancelled);
        vm.assume(stranger_ != requester && tmc.credits(stranger_) == 0);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNothingToWithdraw.selector, stranger_));
        vm.prank(stranger_);
        tmc.withdraw();
        uint256 before = requester.balance;
        vm.expectEmit(address(tmc));
        emit TasksManager.Withdrawn(requester, r);
        vm.prank(requester);
        tmc.withdraw();
        vm.assertEq(requester.balance - before, r, "paid out");
        vm.assertEq(address(tmc).balance, 0, "nothing left");
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNothingToWithdraw.selector, requester));
        vm.prank(requester);
        tmc.withdraw();
    }
}
