// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

/// @dev What the TMC and MMC need from the UMC (see UsersManager for the packing).
interface IUsersManager {
    function isAdmin(address account) external view returns (bool);
    function isRequester(address account) external view returns (bool);
    function workerId(address account) external view returns (uint32);
    function workerRecord(address account) external view returns (uint32 id, uint256 word);
    function updateInfo(address worker, uint32 domain, uint8 taskType, uint8 flags, uint8 review) external;
    function updateInfoBatch(uint32[] calldata ids, uint32 domain, uint8 taskType, uint8 flags, uint8 review)
        external
        returns (address[] memory workers);
    function candidates(uint32 domain, uint8 taskType)
        external
        view
        returns (uint256[] memory workers, uint256[] memory stats);
    function candidateIds(uint32 domain, uint8 taskType, bool withCounters)
        external
        view
        returns (uint256[] memory ids, uint256[] memory stats);
    function profiles(uint32[] calldata ids, uint32 domain, uint8 taskType)
        external
        view
        returns (uint256[] memory workers, uint256[] memory stats);
}

/// @dev Unpacking of the UMC's packed worker and counter words.
library Packed {
    uint256 internal constant MEMBER_BIT = 1 << 255;
    uint256 internal constant ACTIVE = 1;
    uint256 internal constant IDLE = 2;
    uint256 internal constant MAX_DOMAIN = 47; // UsersManager.MAX_DOMAIN

    function addr(uint256 w) internal pure returns (address) {
        return address(uint160(w));
    }

    function status(uint256 w) internal pure returns (uint256) {
        return uint8(w >> 160);
    }

    function gpu(uint256 w) internal pure returns (uint256) {
        return uint8(w >> 168);
    }

    function cores(uint256 w) internal pure returns (uint256) {
        return uint16(w >> 176);
    }

    function ram(uint256 w) internal pure returns (uint256) {
        return uint16(w >> 192);
    }

    /// @dev Worker id of a candidate word ({IUsersManager.candidates}).
    function id(uint256 w) internal pure returns (uint32) {
        return uint32(w >> 208);
    }

    /// @dev Whether a storage word ({IUsersManager.workerRecord}) covers `domain`.
    function covers(uint256 w, uint256 domain) internal pure returns (bool) {
        return domain <= MAX_DOMAIN && (w >> (208 + domain)) & 1 == 1;
    }

    function assigned(uint256 c) internal pure returns (uint256) {
        return uint48(c);
    }

    function accepted(uint256 c) internal pure returns (uint256) {
        return uint48(c >> 48);
    }

    function completed(uint256 c) internal pure returns (uint256) {
        return uint48(c >> 96);
    }

    function ratingSum(uint256 c) internal pure returns (uint256) {
        return uint48(c >> 144);
    }

    function ratingCount(uint256 c) internal pure returns (uint256) {
        return uint48(c >> 192);
    }
}
