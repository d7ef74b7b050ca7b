// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

import {UsersManager} from "../UsersManager.sol";

/**
 * @title UsersManagerHarness (test only, never deployed by the platform)
 * @dev The UMC plus a bulk registration for the allocation scaling tests and benchmark
 * (benchmarks/allocation_scale.py): registering 10,000 workers one transaction each takes
 * hours on py-evm. Seeded workers are exactly what {addWorker} plus {approveWorker} leave:
 * same storage, same domain lists, same Active queues.
 */
contract UsersManagerHarness is UsersManager {
    constructor(address admin) UsersManager(admin) {}

    /**
     * @dev Registers `n` Active workers with the synthetic addresses `first`, `first + 1`, ...
     * covering `domains`; worker i has 1 + (i + salt) % 64 CPU cores (distinct QoS).
     * Requirements: caller is an admin; the addresses are not workers yet.
     * Emits no per-worker event (test setup).
     */
    function seedWorkers(uint160 first, uint256 n, uint256 domains, uint256 salt) external onlyAdmin {
        for (uint256 i; i < n; ++i) {
            address a = address(first + uint160(i));
            if (workerId[a] != 0) revert UsersAlreadyRegistered(a);
            uint32 id = ++workerCount;
            uint16 cores = uint16(1 + ((i + salt) % 64));
            _workers[id] = Worker(a, Status.Active, 1, cores, 64, uint48(domains));
            workerId[a] = id;
            uint256 rest = domains;
            while (rest != 0) {
                uint256 low = rest & (~rest + 1);
                uint256 d;
                while ((low >> d) != 1) ++d;
                _listWorker(d, id);
                rest ^= low;
            }
            _join(id, domains);
        }
    }
}
