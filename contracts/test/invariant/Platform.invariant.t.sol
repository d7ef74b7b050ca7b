// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

import {Fixture} from "../utils/Fixture.sol";
import {PlatformHandler} from "./PlatformHandler.sol";

/**
 * @dev Stateful invariants over random call sequences of PlatformHandler (runs * depth calls
 * per invariant, foundry.toml [invariant]): money conservation on the TMC and MMC, an event
 * for every counter/credit/count change, allocations equal to the reference greedy top-k,
 * and no role acting for another.
 */
contract PlatformInvariantTest is Fixture {
    PlatformHandler internal handler;

    function setUp() public {
        _deploy();
        handler = new PlatformHandler(umc, tmc, mmc, admin);
        vm.prank(admin);
        umc.setAdmin(address(handler), true); // lets the handler approve workers in init()
        handler.init();
        vm.prank(address(handler));
        umc.setAdmin(address(handler), false); // renounces (removing another needs both)
        _target(address(handler), handler.selectors());
    }

    /// (a) TMC: balance == escrow of unsettled slots + withdrawable credits.
    function invariant_tmcBalanceIsEscrowPlusCredits() public view {
        vm.assertEq(address(tmc).balance, handler.tmcEscrow() + handler.creditsOf(false), "TMC balance");
    }

    /// (a) MMC: balance == withdrawable credits (prices are credited at allocation).
    function invariant_mmcBalanceIsCredits() public view {
        vm.assertEq(address(mmc).balance, handler.creditsOf(true), "MMC balance");
    }

    /// (b) Every counter, credit, task, model and allocation change came with its event.
    function invariant_everyChangeHasItsEvent() public view {
        vm.assertEq(handler.eventViolations(), 0, "change without event");
    }

    /// (c) Every allocation (tasks and models) equals the brute-force reference top-k.
    function invariant_allocationsAreReferenceTopK() public view {
        vm.assertEq(handler.allocationMismatches(), 0, "allocation differs from reference");
    }

    /// (d) No call by an actor without the role succeeded (strangers, other requesters,
    /// other workers).
    function invariant_noRoleActsForAnother() public view {
        vm.assertEq(handler.intrusions(), 0, "an actor acted for another");
    }
}

/// @dev The handler's paths succeed and are checked (so the invariants above are not vacuous):
/// a fixed sequence through every handler function.
contract PlatformHandlerPathsTest is Fixture {
    function test_everyHandlerPathIsExercisedAndChecked() public {
        _deploy();
        PlatformHandler h = new PlatformHandler(umc, tmc, mmc, admin);
        vm.prank(admin);
        umc.setAdmin(address(h), true);
        h.init();
        vm.prank(address(h));
        umc.setAdmin(address(h), false);
        h.addTask(0, 1, 5, 7, 0); // task 1, 2 slots
        h.allocateTask(0, false);
        vm.assertEq(h.allocationsChecked(), 1, "allocation succeeded and was compared");
        vm.assertEq(tmc.offerees(1).length, 2, "two offers");
        h.workerAct(0, 1, 0); // offeree 1 accepts
        h.workerAct(0, 1, 3); // and submits
        h.reviewOutcome(0, 1, 4, true);
        h.workerAct(0, 2, 1); // offeree 0 declines
        h.allocateTask(0, true); // admin re-offers the slot
        vm.assertEq(h.allocationsChecked(), 2, "re-allocation compared");
        h.addModel(0, 3, 3, false);
        h.addModel(1, 5, 1, false);
        h.allocateModel(0, 1, 9, false, 3, 3);
        h.allocateModel(1, 2, 9, true, 4, 2);
        vm.assertEq(h.modelAllocationsChecked(), 2, "model allocations compared");
        h.updateModelRep(0, 0, 5);
        for (uint8 a; a < 11; ++a) h.intrude(a, a, 0);
        vm.assertGe(h.intrusionAttempts(), 9, "intrusions attempted");
        h.warp(2 days - 1);
        h.updateTaskStatus(0, true, 0);
        h.withdraw(0, false);
        h.withdraw(3, true);
        vm.assertEq(h.eventViolations(), 0, "events");
        vm.assertEq(h.allocationMismatches(), 0, "allocations");
        vm.assertEq(h.intrusions(), 0, "roles");
        vm.assertEq(address(tmc).balance, h.tmcEscrow() + h.creditsOf(false), "TMC balance");
        vm.assertEq(address(mmc).balance, h.creditsOf(true), "MMC balance");
    }
}
