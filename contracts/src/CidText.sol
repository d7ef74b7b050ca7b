// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

/**
 * @title CidText
 * @dev The one text form of a CID the chain records: CIDv1 in lowercase base32 (multibase
 * prefix `b`, alphabet a-z 2-7), as `ipfs add --cid-version 1` and the project's store print.
 * Provenance and duplicate checks compare keccak256 of the text, and one CID has many texts
 * (`B` + uppercase base32, base58 `Qm...`, base36 `k...`, base64 `m...`): accepting only one
 * form keeps a re-encoded copy of an outcome from passing as a new CID (docs/chain.md).
 *
 * Within lowercase base32 one byte string still had several spellings: the last character of
 * an unpadded body of L characters carries (5 * L) % 8 bits no byte uses, which a decoder
 * ignores, so a CID whose last character leaves 2 such bits had 4 texts (the 3 others with
 * those bits set). Only the RFC 4648 encoding is accepted: those bits are 0, and L % 8 is not
 * 1, 3 or 6 (lengths no byte string encodes to). backend/store/cid.py refuses the same texts.
 */
library CidText {
    /// Longest CID text accepted: a CIDv1 with a 64-byte digest is 113 characters.
    uint256 internal constant MAX_LENGTH = 128;

    /// @dev True if `cid` is `b` followed by 2 to {MAX_LENGTH} - 1 of a-z and 2-7 that are the
    /// RFC 4648 base32 encoding (no padding) of some bytes: a body length whose remainder
    /// mod 8 is 0, 2, 4, 5 or 7, and the unused low bits of the last character zero
    /// ('a'..'z' = 0..25, '2'..'7' = 26..31).
    function isCanonical(string calldata cid) internal pure returns (bool) {
        bytes calldata b = bytes(cid);
        uint256 n = b.length;
        if (n < 2 || n > MAX_LENGTH || b[0] != "b") return false;
        uint256 body = n - 1;
        uint256 rest = body % 8;
        if (rest == 1 || rest == 3 || rest == 6) return false;
        uint256 v = 0; // value of the last character read
        for (uint256 i = 1; i < n; ++i) {
            uint8 c = uint8(b[i]);
            if (c >= 0x61 && c <= 0x7a) v = c - 0x61; // 'a'..'z' = 0..25
            else if (c >= 0x32 && c <= 0x37) v = c - 0x18; // '2'..'7' = 26..31
            else return false;
        }
        uint256 unused = (5 * body) % 8; // bits of the last character no byte uses
        return v & ((1 << unused) - 1) == 0;
    }
}
