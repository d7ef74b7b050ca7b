// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

/// @dev What the TMC needs from the MMC: whether a CID is already listed as a shared model, so
/// a listed model cannot be handed in as a task's outcome (someone else's work as one's own).
interface IModelsListing {
    /// @dev The model listed with the CID whose keccak256 is `cidHash`; 0 if none.
    function modelOfCid(bytes32 cidHash) external view returns (uint256);
}
