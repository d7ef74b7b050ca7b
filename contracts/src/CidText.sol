// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

/**
 * @title CidText
 * @dev The one text form of a CID the chain records: CIDv1 in lowercase base32 (multibase
 * prefix `b`, alphabet a-z 2-7), as `ipfs add --cid-version 1` and the project's store print.
 * Provenance and duplicate checks compare keccak256 of the text, and one CID has many texts
 * (`B` + uppercase base32, base58 `Qm...`, base36 `k...`, base64 `m...`): accepting only one
 * form keeps a re-encoded copy of an outcome from passing as a new CID (docs/chain.md).
 */
library CidText {
    /// Longest CID text accepted: a CIDv1 with a 64-byte digest is 113 characters.
    uint256 internal constant MAX_LENGTH = 128;

    /// @dev True if `cid` is `b` followed by 1 to {MAX_LENGTH} - 1 of a-z and 2-7.
    function isCanonical(string calldata cid) internal pure returns (bool) {
        bytes calldata b = bytes(cid);
        uint256 n = b.length;
        if (n < 2 || n > MAX_LENGTH || b[0] != "b") return false;
        for (uint256 i = 1; i < n; ++i) {
            bytes1 c = b[i];
            if (!((c >= "a" && c <= "z") || (c >= "2" && c <= "7"))) return false;
        }
        return true;
    }
}
