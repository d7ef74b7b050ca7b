// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

import {Fixture} from "./utils/Fixture.sol";
import {UsersManager} from "../src/UsersManager.sol";
import {TasksManager} from "../src/TasksManager.sol";

/// @dev Fuzz tests of every external state-changing function of the UMC: the valid path
/// (state and event) and each wrong-role / bad-input revert with its exact custom error.
contract UsersManagerFuzzTest is Fixture {
    function setUp() public {
        _deploy();
    }

    function _notAdmin(address a) internal view {
        vm.assume(a != admin);
    }

    // ------------------------------------------------------------------ setAdmin

    function testFuzz_setAdmin_addsAndRemoves(address a) public {
        vm.assume(a != admin);
        vm.expectEmit(address(umc));
        emit UsersManager.AdminUpdated(a, true);
        vm.prank(admin);
        umc.setAdmin(a, true);
        vm.assertTrue(umc.isAdmin(a), "added");
        vm.assertEq(umc.adminCount(), 2, "count up");
        vm.prank(admin);
        umc.setAdmin(admin, false); // an admin removes itself alone
        vm.assertFalse(umc.isAdmin(admin), "removed");
        vm.assertEq(umc.adminCount(), 1, "count down");
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersLastAdmin.selector, a));
        vm.prank(a);
        umc.setAdmin(a, false);
    }

    /// One admin of two or three cannot remove another nor allow a platform contract: the
    /// change waits for a majority, then happens; votes cast before another change lapse.
    function testFuzz_adminAndPlatformChangesNeedAMajority(address b, address c, address rogue) public {
        vm.assume(b != admin && c != admin && b != c && rogue != admin && rogue != b && rogue != c);
        vm.assume(rogue != address(tmc) && rogue != address(mmc));
        vm.prank(admin);
        umc.setAdmin(b, true); // one admin: decides alone
        vm.assertEq(umc.quorum(), 2, "two admins: both");
        bytes32 proposal = umc.changeProposal(umc.ADMIN_CHANGE(), admin, false);
        vm.expectEmit(address(umc));
        emit UsersManager.ChangeVoted(proposal, b, 0, admin, false, 1, 2);
        vm.prank(b);
        umc.setAdmin(admin, false);
        vm.assertTrue(umc.isAdmin(admin), "one vote of two removes nobody");
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersAlreadyVoted.selector, b, proposal));
        vm.prank(b);
        umc.setAdmin(admin, false);
        vm.prank(b);
        umc.setPlatform(rogue, true);
        vm.assertFalse(umc.isPlatform(rogue), "one vote of two allows no contract");
        // a third admin (both vote); the pending votes lapse with the change
        vm.prank(admin);
        umc.setAdmin(c, true);
        vm.assertFalse(umc.isAdmin(c), "needs the second vote");
        vm.expectEmit(address(umc));
        emit UsersManager.AdminUpdated(c, true);
        vm.prank(b);
        umc.setAdmin(c, true);
        vm.assertEq(umc.adminCount(), 3, "three admins");
        vm.assertEq(umc.quorum(), 2, "two of three");
        vm.prank(c);
        umc.setPlatform(rogue, true);
        vm.assertFalse(umc.isPlatform(rogue), "b's vote before c joined lapsed");
        vm.prank(b);
        umc.setPlatform(rogue, true);
        vm.assertTrue(umc.isPlatform(rogue), "two of three allow it");
        // two of three remove the third
        vm.prank(b);
        umc.setAdmin(admin, false);
        vm.assertTrue(umc.isAdmin(admin), "one of three");
        vm.expectEmit(address(umc));
        emit UsersManager.AdminUpdated(admin, false);
        vm.prank(c);
        umc.setAdmin(admin, false);
        vm.assertFalse(umc.isAdmin(admin), "two of three remove");
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotAdmin.selector, admin));
        vm.prank(admin);
        umc.setPlatform(rogue, false);
    }

    function testFuzz_setAdmin_onlyAdmin(address caller, address a, bool on) public {
        _notAdmin(caller);
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotAdmin.selector, caller));
        vm.prank(caller);
        umc.setAdmin(a, on);
    }

    // ------------------------------------------------------------------ setPlatform

    function testFuzz_setPlatform(address caller, address a, bool on) public {
        vm.assume(umc.isPlatform(a) != on); // no change: no event
        vm.expectEmit(address(umc));
        emit UsersManager.PlatformUpdated(a, on);
        vm.prank(admin);
        umc.setPlatform(a, on);
        vm.assertEq(umc.isPlatform(a), on, "platform flag");
        _notAdmin(caller);
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotAdmin.selector, caller));
        vm.prank(caller);
        umc.setPlatform(a, !on);
    }

    // ------------------------------------------------------------------ setApprovalRequired

    function testFuzz_setApprovalRequired(address caller, bool required, address w) public {
        vm.assume(w != address(0) && w != requester);
        vm.expectEmit(address(umc));
        emit UsersManager.ApprovalRequiredUpdated(required);
        vm.prank(admin);
        umc.setApprovalRequired(required);
        vm.prank(w);
        umc.addWorker(1 << DOMAIN, 8, 32, 1);
        UsersManager.Status expect = required ? UsersManager.Status.Pending : UsersManager.Status.Active;
        vm.assertEq(uint256(umc.getWorker(w).status), uint256(expect), "status at registration");
        vm.assertEq(umc.queueLength(DOMAIN), required ? 0 : 1, "queue");
        _notAdmin(caller);
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotAdmin.selector, caller));
        vm.prank(caller);
        umc.setApprovalRequired(!required);
    }

    // ------------------------------------------------------------------ setPoolSize

    function testFuzz_setPoolSize(uint256 size, address caller) public {
        uint256 ok = _bound(size, 1, umc.MAX_POOL_SIZE());
        vm.expectEmit(address(umc));
        emit UsersManager.PoolSizeUpdated(ok);
        vm.prank(admin);
        umc.setPoolSize(ok);
        vm.assertEq(umc.poolSize(), ok, "pool size");
        uint256 bad = size > umc.MAX_POOL_SIZE() ? size : 0;
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersBadPoolSize.selector, bad));
        vm.prank(admin);
        umc.setPoolSize(bad);
        _notAdmin(caller);
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotAdmin.selector, caller));
        vm.prank(caller);
        umc.setPoolSize(ok);
    }

    function testFuzz_poolIsQueuePrefix(uint8 n, uint8 size) public {
        uint256 workers = _bound(n, 1, 40);
        uint256 ps = _bound(size, 1, 40);
        vm.prank(admin);
        umc.setPoolSize(ps);
        for (uint256 i; i < workers; ++i) _worker(address(uint160(0x1000 + i)), 1 << DOMAIN, 8);
        address[] memory pool = umc.pool(DOMAIN);
        address[] memory q = umc.queue(DOMAIN);
        vm.assertEq(q.length, workers, "queue holds every Active worker");
        vm.assertEq(pool.length, workers < ps ? workers : ps, "pool = min(queue, poolSize)");
        for (uint256 i; i < pool.length; ++i) vm.assertEq(pool[i], q[i], "pool is the queue's prefix");
    }

    /// getWorkers pages: the concatenation of consecutive pages is the domain's list in
    /// registration order; a page past the end is empty; page length = min(limit, rest).
    function testFuzz_getWorkersPages(uint8 n, uint8 lim, uint8 off) public {
        uint256 workers = _bound(n, 0, 30);
        uint256 limit = _bound(lim, 1, 40);
        for (uint256 i; i < workers; ++i) _worker(address(uint160(0x1000 + i)), 1 << DOMAIN, 8);
        uint256 seen;
        while (true) {
            UsersManager.Worker[] memory page = umc.getWorkers(DOMAIN, seen, limit);
            uint256 rest = workers - seen;
            vm.assertEq(page.length, rest < limit ? rest : limit, "page length");
            for (uint256 i; i < page.length; ++i) {
                vm.assertEq(page[i].addr, address(uint160(0x1000 + seen + i)), "registration order");
                vm.assertEq(uint8(page[i].status), uint8(UsersManager.Status.Active), "status");
                vm.assertEq(page[i].domains, uint256(1) << DOMAIN, "domains");
            }
            seen += page.length;
            if (page.length < limit) break;
        }
        vm.assertEq(seen, workers, "all workers listed once");
        uint256 offset = workers + _bound(off, 0, 200);
        vm.assertEq(umc.getWorkers(DOMAIN, offset, limit).length, 0, "past the end");
        vm.assertEq(umc.getWorkers(DOMAIN, type(uint256).max, type(uint256).max).length, 0, "huge offset");
    }

    // ------------------------------------------------------------------ addWorker

    function testFuzz_addWorker(address w, uint8 d1, uint8 d2, uint16 cores, uint16 ram, uint8 gpu) public {
        vm.assume(w != address(0));
        uint256 domains = (uint256(1) << (d1 % 48)) | (uint256(1) << (d2 % 48));
        vm.expectEmit(address(umc));
        emit UsersManager.WorkerAdded(w, 1, domains, cores, ram, gpu);
        vm.expectEmit(address(umc));
        emit UsersManager.WorkerStatusUpdated(w, UsersManager.Status.Pending);
        vm.prank(w);
        umc.addWorker(domains, cores, ram, gpu);
        UsersManager.Worker memory rec = umc.getWorker(w);
        vm.assertEq(umc.workerId(w), 1, "id");
        vm.assertEq(rec.addr, w, "addr");
        vm.assertEq(rec.domains, domains, "domains");
        vm.assertEq(rec.cpuCores, cores, "cores");
        vm.assertEq(rec.ramGb, ram, "ram");
        vm.assertEq(rec.gpuSeries, gpu, "gpu");
        vm.assertEq(umc.domainSize(d1 % 48), 1, "listed");
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersAlreadyRegistered.selector, w));
        vm.prank(w);
        umc.addWorker(domains, cores, ram, gpu);
    }

    function testFuzz_addWorker_badDomains(address w, uint256 domains) public {
        vm.assume(w != address(0));
        uint256 bad = domains >> 48 == 0 ? 0 : domains;
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersBadDomains.selector, bad));
        vm.prank(w);
        umc.addWorker(bad, 1, 1, 1);
    }

    function testFuzz_addWorker_tooManyDomains(address w, uint256 seed) public {
        vm.assume(w != address(0));
        uint256 domains = uint256(uint48(seed)) | 0x1f; // >= 5 bits set
        vm.expectRevert(
            abi.encodeWithSelector(UsersManager.UsersTooManyDomains.selector, domains, umc.MAX_WORKER_DOMAINS())
        );
        vm.prank(w);
        umc.addWorker(domains, 1, 1, 1);
    }

    // ------------------------------------------------------------------ approveWorker

    function testFuzz_approveWorker(address w, address caller) public {
        vm.assume(w != address(0) && w != admin);
        vm.prank(w);
        umc.addWorker(1 << DOMAIN, 4, 4, 1);
        _notAdmin(caller);
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotAdmin.selector, caller));
        vm.prank(caller);
        umc.approveWorker(w);
        vm.expectEmit(address(umc));
        emit UsersManager.WorkerApproved(w, admin);
        vm.prank(admin);
        umc.approveWorker(w);
        vm.assertEq(uint256(umc.getWorker(w).status), uint256(UsersManager.Status.Active), "active");
        vm.assertEq(umc.pool(DOMAIN)[0], w, "in pool");
        vm.expectRevert(
            abi.encodeWithSelector(UsersManager.UsersNotPending.selector, w, UsersManager.Status.Active)
        );
        vm.prank(admin);
        umc.approveWorker(w);
    }

    function testFuzz_approveWorker_unknown(address w) public {
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotWorker.selector, w));
        vm.prank(admin);
        umc.approveWorker(w);
    }

    // ------------------------------------------------------------------ removeWorker

    function testFuzz_removeWorker(address w, address caller, bool byAdmin) public {
        vm.assume(w != address(0) && w != admin && caller != w && caller != admin);
        _worker(w, 1 << DOMAIN, 8);
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotSelfOrAdmin.selector, caller, w));
        vm.prank(caller);
        umc.removeWorker(w);
        address by = byAdmin ? admin : w;
        vm.expectEmit(address(umc));
        emit UsersManager.WorkerRemoved(w, by);
        vm.prank(by);
        umc.removeWorker(w);
        vm.assertEq(umc.queueLength(DOMAIN), 0, "left the queue");
        vm.assertEq(uint256(umc.getWorker(w).status), uint256(UsersManager.Status.Removed), "removed");
        vm.expectRevert(
            abi.encodeWithSelector(UsersManager.UsersNotApproved.selector, w, UsersManager.Status.Removed)
        );
        vm.prank(by);
        umc.removeWorker(w);
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersAlreadyRegistered.selector, w));
        vm.prank(w);
        umc.addWorker(1 << DOMAIN, 8, 32, 1);
    }

    // ------------------------------------------------------------------ addRequester

    function testFuzz_addRequester(address a, bool approval) public {
        vm.assume(a != requester);
        vm.prank(admin);
        umc.setApprovalRequired(approval);
        UsersManager.Status s = approval ? UsersManager.Status.Pending : UsersManager.Status.Active;
        vm.expectEmit(address(umc));
        emit UsersManager.RequesterStatusUpdated(a, s);
        if (!approval) {
            vm.expectEmit(address(umc));
            emit UsersManager.RequesterAdded(a);
        }
        vm.prank(a);
        umc.addRequester();
        vm.assertEq(uint8(umc.requesterStatus(a)), uint8(s), "status");
        vm.assertEq(umc.isRequester(a), !approval, "a pending requester is no requester yet");
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersAlreadyRegistered.selector, a));
        vm.prank(a);
        umc.addRequester();
    }

    /// A sybil requester (issue 8 probe): with approval on, a second address of a worker
    /// cannot post a task until an admin approves it.
    function testFuzz_pendingRequesterCannotPostTasks(address a) public {
        vm.assume(a != requester && a != address(0) && a.code.length == 0);
        vm.prank(a);
        umc.addRequester();
        vm.deal(a, 1 ether);
        vm.expectRevert(abi.encodeWithSelector(TasksManager.TasksNotRequester.selector, a));
        vm.prank(a);
        tmc.addTask{value: 1e9}(_params(1));
        vm.prank(admin);
        umc.approveRequester(a);
        vm.prank(a);
        tmc.addTask{value: 1e9}(_params(1));
    }

    function testFuzz_approveRequester(address a, address caller) public {
        vm.assume(a != requester && caller != admin);
        vm.prank(a);
        umc.addRequester();
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotAdmin.selector, caller));
        vm.prank(caller);
        umc.approveRequester(a);
        vm.expectEmit(address(umc));
        emit UsersManager.RequesterApproved(a, admin);
        vm.expectEmit(address(umc));
        emit UsersManager.RequesterStatusUpdated(a, UsersManager.Status.Active);
        vm.expectEmit(address(umc));
        emit UsersManager.RequesterAdded(a);
        vm.prank(admin);
        umc.approveRequester(a);
        vm.assertTrue(umc.isRequester(a), "approved");
        vm.expectRevert(
            abi.encodeWithSelector(UsersManager.UsersRequesterNotPending.selector, a, UsersManager.Status.Active)
        );
        vm.prank(admin);
        umc.approveRequester(a);
    }

    function testFuzz_removeRequester(address caller, bool byAdmin, bool pending) public {
        address r = byAdmin ? requester : caller;
        vm.assume(caller != admin && caller != requester && caller != address(0));
        if (!byAdmin) {
            vm.prank(admin);
            umc.setApprovalRequired(pending);
            vm.prank(r);
            umc.addRequester();
            // a stranger removes nobody
            vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotSelfOrAdmin.selector, requester, r));
            vm.prank(requester);
            umc.removeRequester(r);
        }
        address by = byAdmin ? admin : r;
        vm.expectEmit(address(umc));
        emit UsersManager.RequesterRemoved(r, by);
        vm.expectEmit(address(umc));
        emit UsersManager.RequesterStatusUpdated(r, UsersManager.Status.Removed);
        vm.prank(by);
        umc.removeRequester(r);
        vm.assertFalse(umc.isRequester(r), "removed");
        vm.expectRevert(
            abi.encodeWithSelector(UsersManager.UsersRequesterNotRegistered.selector, r, UsersManager.Status.Removed)
        );
        vm.prank(by);
        umc.removeRequester(r);
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersAlreadyRegistered.selector, r));
        vm.prank(r);
        umc.addRequester(); // a removed address cannot come back
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersRequesterNotPending.selector, r, UsersManager.Status.Removed));
        vm.prank(admin);
        umc.approveRequester(r);
    }

    // ------------------------------------------------------------------ updateStatus

    function testFuzz_updateStatus(address w, uint8 raw) public {
        vm.assume(w != address(0) && w != admin);
        _worker(w, 1 << DOMAIN | 1 << 3, 8);
        UsersManager.Status s = UsersManager.Status(_bound(raw, 0, 4));
        if (s != UsersManager.Status.Active && s != UsersManager.Status.Idle) {
            vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersBadStatus.selector, uint8(s)));
            vm.prank(w);
            umc.updateStatus(s);
            return;
        }
        vm.expectEmit(address(umc));
        emit UsersManager.WorkerStatusUpdated(w, s);
        vm.prank(w);
        umc.updateStatus(s);
        uint256 inQueue = s == UsersManager.Status.Active ? 1 : 0;
        vm.assertEq(umc.queueLength(DOMAIN), inQueue, "domain 7 queue");
        vm.assertEq(umc.queueLength(3), inQueue, "domain 3 queue");
    }

    function testFuzz_updateStatus_wrongRole(address a) public {
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotWorker.selector, a));
        vm.prank(a);
        umc.updateStatus(UsersManager.Status.Active);
    }

    function testFuzz_updateStatus_pendingCannot(address w) public {
        vm.assume(w != address(0));
        vm.prank(w);
        umc.addWorker(1 << DOMAIN, 1, 1, 1);
        vm.expectRevert(
            abi.encodeWithSelector(UsersManager.UsersNotApproved.selector, w, UsersManager.Status.Pending)
        );
        vm.prank(w);
        umc.updateStatus(UsersManager.Status.Active);
    }

    // ------------------------------------------------------------------ updateCapabilities

    function testFuzz_updateCapabilities(
        address w,
        uint16 cores,
        uint16 ram,
        uint8 gpu,
        address other,
        bool idle,
        bool approval
    ) public {
        vm.assume(w != address(0) && w != admin && other != w);
        _worker(w, 1 << DOMAIN, 8); // 8 cores, 32 GB, GPU 1
        if (idle) {
            vm.prank(w);
            umc.updateStatus(UsersManager.Status.Idle);
        }
        vm.prank(admin);
        umc.setApprovalRequired(approval);
        bool changed = cores != 8 || ram != 32 || gpu != 1;
        UsersManager.Status before = idle ? UsersManager.Status.Idle : UsersManager.Status.Active;
        vm.expectEmit(address(umc));
        emit UsersManager.WorkerCapabilitiesUpdated(w, cores, ram, gpu);
        if (changed && approval) {
            vm.expectEmit(address(umc));
            emit UsersManager.WorkerStatusUpdated(w, UsersManager.Status.Pending);
        }
        vm.prank(w);
        umc.updateCapabilities(cores, ram, gpu);
        UsersManager.Worker memory rec = umc.getWorker(w);
        vm.assertEq(rec.cpuCores, cores, "cores");
        vm.assertEq(rec.ramGb, ram, "ram");
        vm.assertEq(rec.gpuSeries, gpu, "gpu");
        vm.assertEq(rec.domains, 1 << DOMAIN, "domains kept");
        // approval covers the declared capabilities: a change needs re-approval
        UsersManager.Status want = changed && approval ? UsersManager.Status.Pending : before;
        vm.assertEq(uint8(rec.status), uint8(want), "status");
        vm.assertEq(umc.queueLength(DOMAIN), want == UsersManager.Status.Active ? 1 : 0, "queue");
        if (want == UsersManager.Status.Pending) {
            // re-approval restores the status the worker chose: Active (a candidate again)
            // or Idle (paused, out of the queue until it sets itself Active)
            vm.expectEmit(address(umc));
            emit UsersManager.WorkerStatusUpdated(w, before);
            vm.prank(admin);
            umc.approveWorker(w);
            vm.assertEq(uint8(umc.getWorker(w).status), uint8(before), "re-approved as before");
            vm.assertEq(umc.queueLength(DOMAIN), idle ? 0 : 1, "a candidate again only if Active");
            if (idle) {
                vm.prank(w);
                umc.updateStatus(UsersManager.Status.Active);
                vm.assertEq(umc.queueLength(DOMAIN), 1, "its own choice to come back");
                // the next change while Active is re-approved as Active: nothing left over
                vm.prank(w);
                umc.updateCapabilities(cores == 0 ? 1 : cores - 1, ram, gpu);
                vm.prank(admin);
                umc.approveWorker(w);
                vm.assertEq(uint8(umc.getWorker(w).status), uint8(UsersManager.Status.Active), "active");
            }
        }
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotWorker.selector, other));
        vm.prank(other);
        umc.updateCapabilities(cores, ram, gpu);
    }

    /// An approval covers the values the admin reviewed: a Pending worker cannot swap in
    /// others before the approval is mined, and a removed worker cannot change anything.
    function testFuzz_updateCapabilities_frozenWhilePendingOrRemoved(uint16 cores, uint16 ram, uint8 gpu) public {
        vm.assume(cores != 8 || ram != 32 || gpu != 1);
        address w = address(0xBEEF);
        vm.prank(admin);
        umc.setApprovalRequired(true);
        vm.prank(w);
        umc.addWorker(1 << DOMAIN, 8, 32, 1);
        vm.expectRevert(
            abi.encodeWithSelector(UsersManager.UsersNotApproved.selector, w, UsersManager.Status.Pending)
        );
        vm.prank(w);
        umc.updateCapabilities(cores, ram, gpu);
        vm.prank(w);
        umc.updateCapabilities(8, 32, 1); // the same values: a no-op, allowed
        vm.prank(admin);
        umc.approveWorker(w);
        UsersManager.Worker memory rec = umc.getWorker(w);
        vm.assertEq(rec.cpuCores, 8, "approved the reviewed cores");
        vm.prank(w);
        umc.removeWorker(w);
        vm.expectRevert(
            abi.encodeWithSelector(UsersManager.UsersNotApproved.selector, w, UsersManager.Status.Removed)
        );
        vm.prank(w);
        umc.updateCapabilities(8, 32, 1);
    }

    // ------------------------------------------------------------------ updateInfo

    function testFuzz_updateInfo(uint8 flags, uint8 review, uint8 taskType) public {
        address w = _actor("worker");
        _worker(w, 1 << DOMAIN, 8);
        vm.prank(admin);
        umc.setPlatform(admin, true);
        uint8 f = uint8(_bound(flags, 1, 15));
        uint8 t = uint8(_bound(taskType, 0, 1));
        uint8 r = uint8(_bound(review, 0, 5));
        // assigned/accepted first so every combination keeps completed <= accepted <= assigned
        vm.startPrank(admin);
        umc.updateInfo(w, DOMAIN, t, 1, 0);
        umc.updateInfo(w, DOMAIN, t, 1 | 2, 0); // assigned 2, accepted 1
        vm.stopPrank();
        vm.prank(admin);
        umc.updateInfo(w, DOMAIN, t, f, r);
        UsersManager.Counters memory c = umc.counters(w, DOMAIN, t);
        vm.assertEq(c.assigned, 2 + (f & 1), "assigned");
        vm.assertEq(c.accepted, 1 + ((f >> 1) & 1), "accepted");
        vm.assertEq(c.completed, (f >> 2) & 1, "completed");
        vm.assertEq(c.ratingCount, (f >> 3) & 1, "ratingCount");
        vm.assertEq(c.ratingSum, (f & 8) != 0 ? r : 0, "ratingSum");
        UsersManager.Counters memory other = umc.counters(w, DOMAIN, 1 - t);
        vm.assertEq(other.assigned, 0, "other task type untouched");
    }

    function testFuzz_updateInfo_rejects(address caller, uint8 flags, uint8 review, uint8 taskType) public {
        address w = _actor("worker");
        _worker(w, 1 << DOMAIN, 8);
        vm.assume(caller != address(tmc) && caller != address(mmc));
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotPlatform.selector, caller));
        vm.prank(caller);
        umc.updateInfo(w, DOMAIN, 0, 1, 0);

        vm.startPrank(address(tmc));
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotWorker.selector, caller));
        umc.updateInfo(caller, DOMAIN, 0, 1, 0);
        uint8 badType = uint8(_bound(taskType, 2, 255));
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersBadTaskType.selector, badType));
        umc.updateInfo(w, DOMAIN, badType, 1, 0);
        uint8 badFlags = flags > 15 ? flags : 0;
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersBadFlags.selector, badFlags));
        umc.updateInfo(w, DOMAIN, 0, badFlags, 0);
        uint8 badReview = uint8(_bound(review, 6, 255));
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersBadReview.selector, badReview));
        umc.updateInfo(w, DOMAIN, 0, 8, badReview);
        // completed before accepted breaks completed <= accepted <= assigned
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersCountersInconsistent.selector, w, DOMAIN, 0));
        umc.updateInfo(w, DOMAIN, 0, 4, 0);
        vm.stopPrank();
    }

    /// Counters only grow: no flag takes an assignment back (the old WITHDRAWN = 16, alone or
    /// combined, is refused like any flag above 15), whatever the counters hold.
    function testFuzz_updateInfo_countersOnlyGrow(uint8 assigned, uint8 accepted, uint8 flags) public {
        address w = _actor("worker");
        _worker(w, 1 << DOMAIN, 8);
        uint256 a = _bound(assigned, 0, 6);
        uint256 ac = _bound(accepted, 0, a);
        vm.startPrank(address(tmc));
        for (uint256 i; i < a; ++i) umc.updateInfo(w, DOMAIN, 0, i < ac ? 1 | 2 : 1, 0);
        uint8 f = uint8(_bound(flags, 16, 255));
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersBadFlags.selector, f));
        umc.updateInfo(w, DOMAIN, 0, f, 0);
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersBadFlags.selector, uint8(16)));
        umc.updateInfo(w, DOMAIN, 0, 16, 0);
        vm.stopPrank();
        vm.assertEq(umc.counters(w, DOMAIN, 0).assigned, a, "assigned untouched");
        vm.assertEq(umc.counters(w, DOMAIN, 0).accepted, ac, "accepted untouched");
    }

    // ------------------------------------------------------------------ updateInfoBatch

    /// The batch is many {updateInfo} calls: entries in order, a repeated id counted per
    /// entry, one WorkerInfoUpdated per entry with the running counters, the addresses back.
    function testFuzz_updateInfoBatch(uint8 n, uint256 seed, uint8 taskType) public {
        uint256 workers = _bound(n, 1, 6);
        for (uint256 i; i < workers; ++i) _worker(address(uint160(0x1000 + i)), 1 << DOMAIN, 8);
        uint8 t = uint8(_bound(taskType, 0, 1));
        uint256 len = _bound(seed, 0, 8);
        uint32[] memory ids = new uint32[](len);
        uint48[] memory seen = new uint48[](workers);
        for (uint256 i; i < len; ++i) {
            uint256 k = uint256(keccak256(abi.encode(seed, i))) % workers;
            ids[i] = umc.workerId(address(uint160(0x1000 + k)));
            ++seen[k];
            vm.expectEmit(true, true, true, true, address(umc));
            emit UsersManager.WorkerInfoUpdated(address(uint160(0x1000 + k)), DOMAIN, t, seen[k], 0, 0, 0, 0);
        }
        vm.prank(address(mmc));
        address[] memory got = umc.updateInfoBatch(ids, DOMAIN, t, 1, 0);
        vm.assertEq(got.length, len, "one address per entry");
        for (uint256 i; i < len; ++i) vm.assertEq(umc.workerId(got[i]), ids[i], "address of the id");
        for (uint256 k; k < workers; ++k) {
            vm.assertEq(umc.counters(address(uint160(0x1000 + k)), DOMAIN, t).assigned, seen[k], "per entry");
        }
    }

    function testFuzz_updateInfoBatch_rejects(address caller, uint32 unknown, uint8 flags) public {
        address w = _actor("worker");
        _worker(w, 1 << DOMAIN, 8);
        uint32[] memory ids = new uint32[](1);
        ids[0] = umc.workerId(w);
        vm.assume(caller != address(tmc) && caller != address(mmc));
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotPlatform.selector, caller));
        vm.prank(caller);
        umc.updateInfoBatch(ids, DOMAIN, 0, 1, 0);

        vm.startPrank(address(mmc));
        uint32 bad = unknown == ids[0] ? 0 : unknown; // 0 and unused ids are no worker
        uint32[] memory two = new uint32[](2);
        (two[0], two[1]) = (ids[0], bad);
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersNotWorkerId.selector, bad));
        umc.updateInfoBatch(two, DOMAIN, 0, 1, 0);
        uint8 badFlags = flags > 15 ? flags : 0;
        vm.expectRevert(abi.encodeWithSelector(UsersManager.UsersBadFlags.selector, badFlags));
        umc.updateInfoBatch(ids, DOMAIN, 0, badFlags, 0);
        vm.stopPrank();
        vm.assertEq(umc.counters(w, DOMAIN, 0).assigned, 0, "nothing counted by a reverted batch");
    }

    // ------------------------------------------------------------------ candidateIds

    /// candidateIds is {candidates} without the worker words: the pool's ids in queue order,
    /// and the same counters (none unless asked).
    function testFuzz_candidateIds(uint8 n, uint8 size, bool withCounters) public {
        uint256 workers = _bound(n, 0, 30);
        vm.prank(admin);
        umc.setPoolSize(_bound(size, 1, 40));
        for (uint256 i; i < workers; ++i) _worker(address(uint160(0x1000 + i)), 1 << DOMAIN, 8);
        if (workers > 0) {
            vm.prank(address(tmc));
            umc.updateInfo(address(uint160(0x1000)), DOMAIN, 1, 1, 0);
        }
        (uint256[] memory ids, uint256[] memory stats) = umc.candidateIds(DOMAIN, 1, withCounters);
        (, uint256[] memory want) = umc.candidates(DOMAIN, 1);
        address[] memory pool = umc.pool(DOMAIN);
        vm.assertEq(ids.length, pool.length, "the pool's size");
        vm.assertEq(stats.length, withCounters ? pool.length : 0, "counters only when asked");
        for (uint256 i; i < ids.length; ++i) {
            vm.assertEq(ids[i], umc.workerId(pool[i]), "the pool's workers, in order");
            if (withCounters) vm.assertEq(stats[i], want[i], "the same counters");
        }
    }
}
