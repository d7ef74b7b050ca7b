// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

import {TestBase} from "./Vm.sol";
import {UsersManager} from "../../src/UsersManager.sol";
import {TasksManager} from "../../src/TasksManager.sol";
import {ModelsManager} from "../../src/ModelsManager.sol";
import {IUsersManager} from "../../src/IUsersManager.sol";
import {IModelsListing} from "../../src/IModelsListing.sol";
import {ITasksOutcomes} from "../../src/ITasksOutcomes.sol";

/// @dev The platform as backend/chain/platform.py deploys it (same constructor arguments),
/// plus helpers to register actors and post tasks.
abstract contract Fixture is TestBase {
    uint64 internal constant W1 = 100_000; // Eq. 20 weight 0.1 (platform.W1_DEFAULT)
    uint32 internal constant ACCEPT_WINDOW = 3_600;
    uint32 internal constant REVIEW_WINDOW = 7 days;
    uint256 internal constant ALL_GPUS_BUT_NONE = type(uint256).max - 1;
    uint32 internal constant DOMAIN = 7;
    uint40 internal constant DURATION = 1 days;

    UsersManager internal umc;
    TasksManager internal tmc;
    ModelsManager internal mmc;
    address internal admin;
    address internal requester;
    address internal stranger;

    function _deploy() internal {
        admin = _actor("admin");
        requester = _actor("requester");
        stranger = _actor("stranger");
        vm.warp(1_700_000_000);
        umc = new UsersManager(admin);
        tmc = new TasksManager(IUsersManager(address(umc)), W1, ACCEPT_WINDOW, REVIEW_WINDOW, ALL_GPUS_BUT_NONE);
        mmc = new ModelsManager(IUsersManager(address(umc)), ITasksOutcomes(address(tmc)));
        vm.startPrank(admin);
        umc.setPlatform(address(tmc), true);
        umc.setPlatform(address(mmc), true);
        tmc.setModels(IModelsListing(address(mmc)));
        vm.stopPrank();
        vm.prank(requester);
        umc.addRequester();
        vm.prank(admin);
        umc.approveRequester(requester); // approval is on by default: requesters wait for it too
        vm.deal(requester, 1e30);
    }

    /// @dev Registers and approves `w` as a worker of `domains`.
    function _worker(address w, uint256 domains, uint16 cores) internal {
        vm.prank(w);
        umc.addWorker(domains, cores, 32, 1);
        vm.prank(admin);
        umc.approveWorker(w);
    }

    /// @dev `who` commits `cid` (TMC.commitCid) and the chain moves one block on, so the CID
    /// may be revealed (submitOutcome, addModel) next.
    function _commit(address who, string memory cid) internal {
        vm.prank(who);
        tmc.commitCid(keccak256(abi.encodePacked(cid, who)));
        vm.roll(vm.getBlockNumber() + 1);
    }

    function _params(uint8 numWorkers) internal pure returns (TasksManager.TaskParams memory p) {
        p = TasksManager.TaskParams(DOMAIN, numWorkers, 0, 0, 0, 0, DURATION, "task");
    }

    function _task(uint8 numWorkers, uint256 reward) internal returns (uint256) {
        vm.prank(requester);
        return tmc.addTask{value: reward * numWorkers}(_params(numWorkers));
    }
}
