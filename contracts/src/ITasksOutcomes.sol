// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

/// @dev What the MMC needs from the TMC: who submitted an outcome CID and how its requester
/// judged it (model provenance, thesis 7.7).
interface ITasksOutcomes {
    enum Verdict {
        None, // no task outcome has this CID
        Pending, // submitted, not reviewed yet
        Accepted, // accepted by the requester, or paid unreviewed at close
        Rejected // rejected by the requester (slot refunded)
    }

    /// @dev The worker and task of the outcome whose CID hashes to `cidHash`
    /// (keccak256 of the CID's UTF-8 bytes) and its verdict; (0, 0, None) if none.
    function outcomeOf(bytes32 cidHash) external view returns (address worker, uint256 taskId, Verdict verdict);

    /// @dev Whether `commitment` (keccak256(cid ++ worker)) was committed in an earlier block
    /// than this one (commit-reveal of CIDs: the TMC's commitCid).
    function committedBefore(bytes32 commitment) external view returns (bool);

    /// @dev The domain of task `taskId` (0 for an id that names no task): an outcome is listed
    /// as a model of its task's domain only (the MMC's provenance rule).
    function taskDomain(uint256 taskId) external view returns (uint32);
}
