// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

import {ModelsManager} from "../ModelsManager.sol";
import {IUsersManager} from "../IUsersManager.sol";
import {ITasksOutcomes} from "../ITasksOutcomes.sol";

/**
 * @title ModelsManagerHarness (test only, never deployed by the platform)
 * @dev The MMC plus a bulk listing for the allocation scaling tests and benchmark: the
 * storage {addModel} leaves (model record in its owner list, its locator, the domain list,
 * owner count), without the
 * CID text and the event.
 */
contract ModelsManagerHarness is ModelsManager {
    constructor(IUsersManager umc_, ITasksOutcomes tmc_) ModelsManager(umc_, tmc_) {}

    /**
     * @dev Lists `perOwner` models in `domain` for each worker id in [firstOwner, firstOwner
     * + owners), with two environment attributes (i % 7, i % 5) for the i-th model.
     * Requirements: caller is a consortium admin.
     */
    function seedModels(uint32 firstOwner, uint256 owners, uint256 perOwner, uint32 domain) external {
        seedModelsDims(firstOwner, owners, perOwner, domain, 2);
    }

    /**
     * @dev {seedModels} with `dims` (2..MAX_ENV_DIMS) attributes: (i % 7, i % 5, then
     * (i + j) % 7 for attribute j), packed as {addModel} packs them (4 in the model word, 8
     * per tail word), for the worst case of the allocation benchmark.
     */
    function seedModelsDims(uint32 firstOwner, uint256 owners, uint256 perOwner, uint32 domain, uint256 dims)
        public
    {
        if (!umc.isAdmin(msg.sender)) revert ModelsNotAdmin(msg.sender);
        if (dims < 2 || dims > MAX_ENV_DIMS) revert ModelsBadEnv(dims);
        for (uint256 o; o < owners; ++o) {
            uint32 ownerId = firstOwner + uint32(o);
            for (uint256 k; k < perOwner; ++k) {
                uint256 modelId = ++_g.modelCount;
                uint256 head = (modelId % 7) | ((modelId % 5) << 32);
                uint256 tail = 0;
                for (uint256 j = 2; j < dims; ++j) {
                    uint256 v = (modelId + j) % 7;
                    if (j < 4) head |= v << (32 * j);
                    else tail |= v << (32 * (j - 4));
                }
                if (dims > 4) _envTail[modelId][0] = tail;
                _listModel(ownerId, domain, modelId, dims, head);
                _domainModels[domain].push(uint32(modelId));
            }
            _owners[ownerId].modelCount += uint32(perOwner);
        }
    }
}
