// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

/**
 * @title ReentrantWorker (test double, never deployed by the platform)
 * @dev A contract account acting as a worker through {forward}. When paid it either
 * re-enters `withdraw()` of the paying contract (mode Reenter: records whether the inner call
 * succeeded and its revert selector, then accepts the payment) or rejects the payment
 * (mode Reject). Used to show that payouts pay once and survive hostile receivers.
 */
contract ReentrantWorker {
    enum Mode {
        Accept,
        Reenter,
        Reject
    }

    Mode public mode;
    uint256 public received;
    bool public reentryOk;
    bytes4 public reentrySelector;

    function setMode(Mode m) external {
        mode = m;
    }

    /// @dev Calls `target` with `data` as this contract, bubbling any revert unchanged.
    function forward(address target, bytes calldata data) external payable returns (bytes memory ret) {
        bool ok;
        (ok, ret) = target.call{value: msg.value}(data);
        if (!ok) {
            assembly {
                revert(add(ret, 32), mload(ret))
            }
        }
    }

    receive() external payable {
        if (mode == Mode.Reject) revert();
        received += msg.value;
        if (mode == Mode.Reenter) {
            (bool ok, bytes memory ret) = msg.sender.call(abi.encodeWithSignature("withdraw()"));
            reentryOk = ok;
            if (ret.length >= 4) reentrySelector = bytes4(ret);
        }
    }
}
