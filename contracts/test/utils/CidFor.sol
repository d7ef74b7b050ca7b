// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

/// @dev A CID text in the form the contracts accept (CidText: `b` + lowercase base32, 59
/// characters like a sha2-256 CIDv1), distinct for distinct seeds, for tests that need many.
function cidFor(bytes memory seed) pure returns (string memory) {
    bytes memory alphabet = "abcdefghijklmnopqrstuvwxyz234567";
    uint256 h = uint256(keccak256(seed));
    bytes memory out = new bytes(59);
    out[0] = "b";
    for (uint256 i = 1; i < 59; ++i) {
        out[i] = alphabet[i <= 52 ? (h >> (5 * (i - 1))) & 31 : 0];
    }
    return string(out);
}
