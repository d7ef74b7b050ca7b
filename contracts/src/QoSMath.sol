// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

import {Math} from "@openzeppelin/contracts/utils/math/Math.sol";

/**
 * @title QoSMath
 * @dev Fixed-point recruitment formulas of the thesis (Eq. 10-13, 16-23), bit-exact with the
 * `*_fixed` functions of backend/chain/qos.py (the differential tests compare them).
 *
 * Fixed point: values in [0, 1] (reputations, ratings, expertise, CC, weights, distances,
 * QoS) are unsigned integers scaled by ONE = 1e6, so 6 decimal digits survive and every
 * product of four terms stays below 1e24 < 2^80 (no overflow in uint256; see qos.py for the
 * full bound list). Every division floors, as Python's `//`.
 */
library QoSMath {
    uint256 internal constant ONE = 1e6;
    uint256 internal constant HALF = 5e5; // new users start at 0.5 (thesis line 1078)
    uint256 internal constant REVIEW_MAX = 5; // reviews are integers in [0, 5]

    // (2/pi) atan(t) ~ t*(C1 - C3 t^2 + C5 t^4 - C7 t^6 + C9 t^8) on [0, 1], scaled by ONE
    // (coefficients from qos.py; max error 1.2e-5 including the fixed-point floors).
    uint256 private constant C1 = 636_535;
    uint256 private constant C3 = 210_279;
    uint256 private constant C5 = 114_693;
    uint256 private constant C7 = 54_213;
    uint256 private constant C9 = 13_271;

    /// @dev Eq. 17-19: Rep = sqrt(CM * CP) = sqrt(E / A) (Ac cancels), floored in fixed point.
    /// 0.5 with no offers yet, 0 when offers were made but none accepted.
    function reputation(uint256 assigned, uint256 accepted, uint256 completed)
        internal
        pure
        returns (uint256)
    {
        if (assigned == 0) return HALF;
        if (accepted == 0) return 0;
        return Math.sqrt((completed * ONE * ONE) / assigned);
    }

    /// @dev Rating: mean review / REVIEW_MAX in [0, 1]; 0.5 before the first review.
    /// Also Eq. 10 and Eq. 11 (total review / allocation count).
    function rating(uint256 sum, uint256 count) internal pure returns (uint256) {
        if (count == 0) return HALF;
        return (sum * ONE) / (count * REVIEW_MAX);
    }

    /// @dev Eq. 16: Exp = N / N_max over the eligible candidates; 0.5 when N_max == 0.
    function expertise(uint256 n, uint256 nMax) internal pure returns (uint256) {
        if (nMax == 0) return HALF;
        return (n * ONE) / nMax;
    }

    /// @dev Eq. 20: CC = (2/pi) atan(x / ONE) with x = w1 * cores (w1 scaled by ONE).
    /// For x > ONE, atan(x) = pi/2 - atan(1/x).
    function atanFixed(uint256 x) internal pure returns (uint256) {
        if (x <= ONE) return _atanUnit(x);
        return ONE - _atanUnit((ONE * ONE) / x);
    }

    function _atanUnit(uint256 t) private pure returns (uint256) {
        unchecked {
            // t <= ONE, so every product below is < 2^60: unchecked is safe.
            // Powers floored at each step on purpose: bit-exact with qos.py's _atan_unit_fixed
            // (the differential tests compare them); the error budget (1.2e-5) includes the floors.
            // slither-disable-next-line divide-before-multiply
            uint256 t2 = (t * t) / ONE;
            uint256 t3 = (t2 * t) / ONE;
            uint256 t5 = (t3 * t2) / ONE;
            // Same floors as qos.py (see above).
            // slither-disable-next-line divide-before-multiply
            uint256 t7 = (t5 * t2) / ONE;
            // Same floors as qos.py (see above).
            // slither-disable-next-line divide-before-multiply
            uint256 t9 = (t7 * t2) / ONE;
            uint256 pos = C1 * t + C5 * t5 + C9 * t9;
            uint256 neg = C3 * t3 + C7 * t7;
            return (pos - neg) / ONE; // pos >= neg on [0, ONE] (checked in qos tests)
        }
    }

    /**
     * @dev Greedy top-k (thesis 7.6): insert candidate `i` with score `q` into the arrays
     * `idx`/`qs` (length k, sorted best first, `count` entries used). A later candidate enters
     * only with a strictly higher score, so ties keep the earlier registration ahead.
     * O(k) per candidate, no full sort. Returns the new count.
     */
    function insertTop(uint256[] memory idx, uint256[] memory qs, uint256 count, uint256 i, uint256 q)
        internal
        pure
        returns (uint256)
    {
        uint256 k = idx.length;
        uint256 pos;
        unchecked {
            if (count < k) {
                pos = count;
                ++count;
            } else if (k != 0 && q > qs[k - 1]) {
                pos = k - 1;
            } else {
                return count;
            }
            while (pos > 0 && qs[pos - 1] < q) {
                qs[pos] = qs[pos - 1];
                idx[pos] = idx[pos - 1];
                --pos;
            }
        }
        qs[pos] = q;
        idx[pos] = i;
        return count;
    }
}
