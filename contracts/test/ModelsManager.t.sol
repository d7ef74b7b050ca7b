// SPDX-License-Identifier: MIT
pragma solidity ^0.8.24;

import {cidFor} from "./utils/CidFor.sol";
import {Fixture} from "./utils/Fixture.sol";
import {ModelsManager} from "../src/ModelsManager.sol";
import {TasksManager} from "../src/TasksManager.sol";
import {ITasksOutcomes} from "../src/ITasksOutcomes.sol";

/// @dev Fuzz tests of every external state-changing function of the MMC: valid path (state,
/// money, event) and wrong-role / bad-input reverts with the exact custom error.
contract ModelsManagerFuzzTest is Fixture {
    address internal owner;
    address internal owner2;

    function setUp() public {
        _deploy();
        owner = _actor("owner");
        owner2 = _actor("owner2");
        _worker(owner, 1 << DOMAIN, 8);
        _worker(owner2, 1 << DOMAIN, 16);
    }

    function _env(uint32 a, uint32 b) internal pure returns (uint32[] memory e) {
        e = new uint32[](2);
        (e[0], e[1]) = (a, b);
    }

    function _model(address who, string memory cid, uint32 a, uint32 b) internal returns (uint256) {
        _commit(who, cid);
        vm.prank(who);
        return mmc.addModel(cid, "desc", DOMAIN, _env(a, b));
    }

    function _request(uint8 n, ModelsManager.Metric metric) internal pure returns (ModelsManager.ModelRequest memory r) {
        r = ModelsManager.ModelRequest(DOMAIN, n, metric, 0, 0, 0, _env(3, 3), new uint32[](0));
    }

    // ------------------------------------------------------------------ admin setters

    function testFuzz_setMinModelPrice(uint256 price, address caller) public {
        uint256 ok = _bound(price, 1, type(uint80).max);
        vm.expectEmit(address(mmc));
        emit ModelsManager.MinModelPriceUpdated(ok);
        vm.prank(admin);
        mmc.setMinModelPrice(ok);
        vm.assertEq(mmc.minModelPrice(), ok, "price");
        vm.expectRevert(ModelsManager.ModelsBadConfig.selector);
        vm.prank(admin);
        mmc.setMinModelPrice(price > type(uint80).max ? price : 0);
        vm.assume(caller != admin);
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNotAdmin.selector, caller));
        vm.prank(caller);
        mmc.setMinModelPrice(ok);
    }

    function testFuzz_setMaxModelsPerOwner(uint256 limit, address caller) public {
        uint256 ok = _bound(limit, 1, mmc.MAX_MODELS_PER_OWNER());
        vm.expectEmit(address(mmc));
        emit ModelsManager.MaxModelsPerOwnerUpdated(ok);
        vm.prank(admin);
        mmc.setMaxModelsPerOwner(ok);
        vm.assertEq(mmc.maxModelsPerOwner(), ok, "limit");
        uint256 bad = limit > mmc.MAX_MODELS_PER_OWNER() ? limit : 0;
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsBadLimit.selector, bad));
        vm.prank(admin);
        mmc.setMaxModelsPerOwner(bad);
        vm.assume(caller != admin);
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNotAdmin.selector, caller));
        vm.prank(caller);
        mmc.setMaxModelsPerOwner(ok);
    }

    // ------------------------------------------------------------------ addModel

    function testFuzz_addModel(string calldata cidSeed, uint32[] calldata env) public {
        string memory cid = cidFor(bytes(cidSeed));
        vm.assume(bytes(cid).length != 0 && env.length <= mmc.MAX_ENV_DIMS());
        _commit(owner, cid);
        _commit(owner2, cid);
        vm.expectEmit(address(mmc));
        emit ModelsManager.ModelAdded(1, owner, DOMAIN, cid, "d", env);
        vm.prank(owner);
        uint256 id = mmc.addModel(cid, "d", DOMAIN, env);
        vm.assertEq(id, 1, "id");
        (ModelsManager.ModelView memory m, string memory storedCid, uint32[] memory storedEnv) = mmc.getModel(id);
        vm.assertEq(m.owner, owner, "owner");
        vm.assertEq(keccak256(bytes(storedCid)), keccak256(bytes(cid)), "cid");
        vm.assertEq(storedEnv.length, env.length, "env length");
        for (uint256 j; j < env.length; ++j) vm.assertEq(storedEnv[j], env[j], "env attribute");
        vm.assertEq(mmc.modelOfCid(keccak256(bytes(cid))), id, "cid index");
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsDuplicateModel.selector, id));
        vm.prank(owner2);
        mmc.addModel(cid, "copy", DOMAIN, env);
    }

    /// @dev domainModelsPage: positions [offset, offset + count) in listing order and the total;
    /// shorter at the end, empty for count 0 or an offset at or past the end.
    function testFuzz_domainModelsPage(uint8 listed, uint256 offset, uint256 count) public {
        uint256 n = _bound(listed, 0, 8);
        uint256[] memory ids = new uint256[](n);
        for (uint256 i; i < n; ++i) {
            ids[i] = _model(i % 2 == 0 ? owner : owner2, cidFor(abi.encode("page", i)), 1, 2);
        }
        offset = offset % 3 == 0 ? offset : _bound(offset, 0, n + 2);
        count = count % 3 == 0 ? count : _bound(count, 0, n + 2);
        (uint32[] memory page, uint256 total) = mmc.domainModelsPage(DOMAIN, offset, count);
        vm.assertEq(total, n, "total");
        uint256 expected = offset >= n ? 0 : (n - offset < count ? n - offset : count);
        vm.assertEq(page.length, expected, "page length");
        for (uint256 i; i < page.length; ++i) vm.assertEq(page[i], ids[offset + i], "ids in listing order");
        (page, total) = mmc.domainModelsPage(DOMAIN, 0, 0);
        vm.assertEq(page.length + total, n, "count 0: empty page, the total");
        (page,) = mmc.domainModelsPage(DOMAIN, n, 1);
        vm.assertEq(page.length, 0, "offset at the end");
        (page,) = mmc.domainModelsPage(DOMAIN, 0, type(uint256).max);
        vm.assertEq(page.length, n, "count past the end");
        vm.assertEq(mmc.domainModels(DOMAIN).length, n, "the whole list agrees");
    }

    /// @dev A model's description is at most MAX_DESCRIPTION_BYTES (the gateway's 1,024
    /// characters, at most 4 bytes each).
    function testFuzz_addModel_descriptionCap(uint16 extra) public {
        uint256 cap = mmc.MAX_DESCRIPTION_BYTES();
        string memory cid = cidFor("long description");
        _commit(owner, cid);
        uint256 len = cap + _bound(extra, 1, 4096);
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsDescriptionTooLong.selector, len, cap));
        vm.prank(owner);
        mmc.addModel(cid, string(new bytes(len)), DOMAIN, _env(1, 2));
        vm.prank(owner);
        mmc.addModel(cid, string(new bytes(cap)), DOMAIN, _env(1, 2));
        vm.assertEq(mmc.modelOfCid(keccak256(bytes(cid))), 1, "listed at the cap");
    }

    function testFuzz_addModel_rejects(address caller, uint32 domain, uint8 extra) public {
        vm.assume(caller != owner && caller != owner2);
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNotWorker.selector, caller));
        vm.prank(caller);
        mmc.addModel(cidFor("c"), "d", DOMAIN, _env(1, 1));
        address pending = _actor("pending");
        vm.prank(pending);
        umc.addWorker(1 << DOMAIN, 1, 1, 1);
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNotApproved.selector, pending));
        vm.prank(pending);
        mmc.addModel(cidFor("c"), "d", DOMAIN, _env(1, 1));
        vm.startPrank(owner);
        uint32 bad = uint32(_bound(domain, 48, type(uint32).max));
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsBadDomain.selector, bad));
        mmc.addModel(cidFor("c"), "d", bad, _env(1, 1));
        uint32 other = uint32(_bound(domain, 0, 46));
        if (other >= DOMAIN) ++other;
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsOwnerNotInDomain.selector, owner, other));
        mmc.addModel(cidFor("c"), "d", other, _env(1, 1));
        vm.expectRevert(ModelsManager.ModelsEmptyCid.selector);
        mmc.addModel("", "d", DOMAIN, _env(1, 1));
        // one CID, one text: other encodings of a CID (a re-encoded copy) and junk are refused
        string[11] memory variants = [
            "BAFKREIDOT3J5VVBTHWTYDMN3NY2PQ2CKIBHBUJ5SECH6WPZSXOKRKQNTSY",
            "QmYwAPJzv5CZsnA625s3Xf2nemtYgPpHdWEz79ojWnPbdG",
            "bafkreidot3j5vvbthwtydmn3ny2pq2ckibhbuj5sech6wpzsxokrkqnts1",
            "x",
            "b",
            "b/../../etc",
            // base32 spellings of one CID (bafkrei...yeq) with unused low bits set in the last
            // character, and a body length no bytes encode to
            "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yer",
            "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yes",
            "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yet",
            "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4ye",
            "baaa"
        ];
        for (uint256 i; i < variants.length; ++i) {
            vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsCidNotCanonical.selector, variants[i]));
            mmc.addModel(variants[i], "d", DOMAIN, _env(1, 1));
        }
        vm.stopPrank();
        _commit(owner, "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yeq");
        vm.prank(owner); // the RFC 4648 spelling itself is listed
        mmc.addModel("bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yeq", "d", DOMAIN, _env(1, 1));
        vm.startPrank(owner);
        uint256 len = _bound(extra, mmc.MAX_ENV_DIMS() + 1, 200);
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsBadEnv.selector, len));
        mmc.addModel(cidFor("c"), "d", DOMAIN, new uint32[](len));
        vm.stopPrank();
        for (uint256 i = 1; i < mmc.maxModelsPerOwner(); ++i) { // the first: the spelling above
            _model(owner, cidFor(abi.encodePacked("cid", i)), 1, 1);
        }
        vm.startPrank(owner);
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsOwnerLimit.selector, owner, 8));
        mmc.addModel(cidFor("one-more"), "d", DOMAIN, _env(1, 1));
        vm.stopPrank();
    }

    /// @dev Commit-reveal for own uploads: no listing without the caller's commitment from an
    /// earlier block; a copier that commits a seen CID and lists it in one block is refused.
    function testFuzz_addModel_needsEarlierCommit(string calldata cidSeed) public {
        string memory cid = cidFor(bytes(cidSeed));
        vm.assume(bytes(cid).length != 0);
        bytes32 mine = keccak256(abi.encodePacked(cid, owner));
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsCidNotCommitted.selector, mine));
        vm.prank(owner);
        mmc.addModel(cid, "d", DOMAIN, _env(1, 1)); // never committed
        _commit(owner, cid); // the producer, a block ago
        bytes32 theirs = keccak256(abi.encodePacked(cid, owner2));
        vm.prank(owner2);
        tmc.commitCid(theirs); // the copier, in this block
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsCidNotCommitted.selector, theirs));
        vm.prank(owner2);
        mmc.addModel(cid, "d", DOMAIN, _env(1, 1));
        vm.prank(owner);
        uint256 id = mmc.addModel(cid, "d", DOMAIN, _env(1, 1));
        vm.assertEq(mmc.modelOfCid(keccak256(bytes(cid))), id, "the producer's listing");
    }

    function testFuzz_addModel_provenance(uint8 review, bool accept) public {
        // owner2 submits an outcome; nobody else may list it, owner2 only once accepted
        vm.prank(requester);
        uint256 id = tmc.addTask{value: 1e9}(_params(1));
        vm.prank(requester);
        tmc.allocateTask(id);
        address w = tmc.offerees(id)[0];
        address other = w == owner ? owner2 : owner;
        vm.prank(w);
        tmc.acceptOffer(id);
        _commit(w, cidFor("outcome"));
        vm.prank(w);
        tmc.submitOutcome(id, cidFor("outcome"));
        _commit(other, cidFor("outcome")); // a commitment does not outweigh the outcome record
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNotOutcomeOwner.selector, id, w));
        vm.prank(other);
        mmc.addModel(cidFor("outcome"), "desc", DOMAIN, _env(1, 1));
        vm.expectRevert(
            abi.encodeWithSelector(ModelsManager.ModelsOutcomeNotAccepted.selector, id, ITasksOutcomes.Verdict.Pending)
        );
        vm.prank(w);
        mmc.addModel(cidFor("outcome"), "desc", DOMAIN, _env(1, 1));
        vm.prank(requester);
        tmc.reviewOutcome(id, w, uint8(_bound(review, 0, 5)), accept);
        if (!accept) {
            vm.expectRevert(
                abi.encodeWithSelector(ModelsManager.ModelsOutcomeNotAccepted.selector, id, ITasksOutcomes.Verdict.Rejected)
            );
        }
        vm.prank(w); // its own accepted outcome needs no new commitment (spent by submitOutcome)
        mmc.addModel(cidFor("outcome"), "desc", DOMAIN, _env(1, 1));
    }

    /// An accepted outcome is listed in its task's domain only (held-out pass of 2026-12-05): a
    /// worker covering two domains could list it in the other one, where the requester's
    /// acceptance (outcomeOf) vouched for a domain the task never asked for.
    function testFuzz_addModel_outcomeInItsTaskDomainOnly(uint32 otherSeed) public {
        uint32 other = uint32(_bound(otherSeed, 0, 46));
        if (other >= DOMAIN) ++other; // any domain code but the task's
        address w = _actor("two-domain worker");
        _worker(w, (1 << DOMAIN) | (uint256(1) << other), 1000); // the pool's best: offered first
        uint256 id = _task(1, 1e9);
        vm.prank(requester);
        tmc.allocateTask(id);
        vm.assertEq(tmc.offerees(id)[0], w, "offered");
        vm.prank(w);
        tmc.acceptOffer(id);
        _commit(w, cidFor("two-domain outcome"));
        vm.prank(w);
        tmc.submitOutcome(id, cidFor("two-domain outcome"));
        vm.prank(requester);
        tmc.reviewOutcome(id, w, 5, true);
        vm.assertEq(tmc.taskDomain(id), DOMAIN, "task domain");
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsOutcomeDomainMismatch.selector, id, DOMAIN, other));
        vm.prank(w);
        mmc.addModel(cidFor("two-domain outcome"), "desc", other, _env(1, 1));
        vm.prank(w);
        uint256 modelId = mmc.addModel(cidFor("two-domain outcome"), "desc", DOMAIN, _env(1, 1));
        vm.assertEq(mmc.modelOfCid(keccak256(bytes(cidFor("two-domain outcome")))), modelId, "listed in its domain");
        _commit(w, cidFor("own upload")); // an own upload lists in any domain its owner covers
        vm.prank(w);
        mmc.addModel(cidFor("own upload"), "desc", other, _env(1, 1));
    }

    // ------------------------------------------------------------------ allocateModel

    function testFuzz_allocateModel(uint8 n, uint80 price, bool sharing) public {
        uint256 a = _model(owner, cidFor("m-a"), 3, 3); // exact match
        uint256 b = _model(owner2, cidFor("m-b"), 9, 9);
        uint8 k = uint8(_bound(n, 1, 16));
        uint256 p = _bound(price, 1, 1e24);
        ModelsManager.ModelRequest memory r =
            _request(k, sharing ? ModelsManager.Metric.Sharing : ModelsManager.Metric.Model);
        vm.expectEmit(address(mmc));
        emit ModelsManager.ModelsRequested(1, requester, DOMAIN, r.metric, k, uint80(p));
        vm.prank(requester);
        uint256 allocId = mmc.allocateModel{value: p * k}(r);
        uint256 got = k < 2 ? k : 2;
        vm.assertEq(uint256(mmc.allocState(allocId, a)), 1, "best (exact match) allocated");
        vm.assertEq(uint256(mmc.allocState(allocId, b)), got == 2 ? 1 : 0, "second only with room");
        vm.assertEq(mmc.credits(owner), p, "owner paid once");
        vm.assertEq(mmc.credits(owner2), got == 2 ? p : 0, "second owner");
        vm.assertEq(mmc.credits(requester), (k - got) * p, "unfilled slots refunded");
        vm.assertEq(address(mmc).balance, p * k, "escrow = credits");
        (ModelsManager.ModelView memory m,,) = mmc.getModel(a);
        vm.assertEq(m.allocCount, 1, "Eq. 11 count");
    }

    function testFuzz_allocateModel_rejects(address caller, uint8 n, uint32 threshold, uint256 value) public {
        _model(owner, cidFor("m-a"), 3, 3);
        vm.assume(caller != requester);
        vm.deal(caller, 1 ether);
        ModelsManager.ModelRequest memory r = _request(1, ModelsManager.Metric.Model);
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNotRequester.selector, caller));
        vm.prank(caller);
        mmc.allocateModel{value: 1}(r);
        vm.startPrank(requester);
        r.numModels = n > 16 ? n : 0;
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsBadModelCount.selector, r.numModels));
        mmc.allocateModel{value: 1}(r);
        r.numModels = 2;
        r.domain = uint32(_bound(threshold, 48, type(uint32).max));
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsBadDomain.selector, r.domain));
        mmc.allocateModel{value: 2}(r);
        r.domain = DOMAIN;
        r.minModelReputation = uint32(_bound(threshold, 1e6 + 1, type(uint32).max));
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsBadThreshold.selector, r.minModelReputation));
        mmc.allocateModel{value: 2}(r);
        r.minModelReputation = 0;
        uint256 odd = 2 * _bound(value, 1, 1e20) + 1;
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsBadPayment.selector, odd, 2));
        mmc.allocateModel{value: odd}(r);
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsPriceBelowMinimum.selector, 0, 1));
        mmc.allocateModel{value: 0}(r);
        r.weights = new uint32[](2);
        (r.weights[0], r.weights[1]) = (5e5, 5e5 - 1);
        vm.expectRevert(ModelsManager.ModelsBadWeights.selector);
        mmc.allocateModel{value: 2}(r);
        r.weights = new uint32[](0);
        r.env = new uint32[](3); // no model with three attributes
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNoEligibleModel.selector, DOMAIN));
        mmc.allocateModel{value: 2}(r);
        vm.stopPrank();
        vm.assertEq(mmc.allocCount(), 0, "nothing allocated");
    }

    // ------------------------------------------------------------------ updateModelRep

    function testFuzz_updateModelRep(uint8 review, address stranger_) public {
        uint256 a = _model(owner, cidFor("m-a"), 3, 3);
        vm.prank(requester);
        uint256 allocId = mmc.allocateModel{value: 1e9}(_request(1, ModelsManager.Metric.Sharing));
        vm.assume(stranger_ != requester);
        uint8 r = uint8(_bound(review, 0, 5));
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNotAllocationRequester.selector, allocId, stranger_));
        vm.prank(stranger_);
        mmc.updateModelRep(allocId, a, r);
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNotAllocated.selector, allocId, a + 1));
        vm.prank(requester);
        mmc.updateModelRep(allocId, a + 1, r);
        uint8 bad = uint8(_bound(review, 6, 255));
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsBadReview.selector, bad));
        vm.prank(requester);
        mmc.updateModelRep(allocId, a, bad);
        vm.expectEmit(address(mmc));
        emit ModelsManager.ModelReviewed(allocId, a, r);
        vm.prank(requester);
        mmc.updateModelRep(allocId, a, r);
        (ModelsManager.ModelView memory m,,) = mmc.getModel(a);
        vm.assertEq(m.totalReview, r, "Eq. 11 total");
        vm.assertEq(mmc.ownerRep(owner).totalReview, r, "Eq. 10 total");
        vm.assertEq(umc.counters(owner, DOMAIN, 1).ratingSum, r, "sharing rating");
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNotAllocated.selector, allocId, a));
        vm.prank(requester);
        mmc.updateModelRep(allocId, a, r);
    }

    /// Packed lists: an owner's list of 16 models in a domain spans three words and an
    /// allocation of up to 16 models spans three words; every entry is found, reviewed once,
    /// and a review flags that entry only.
    function testFuzz_packedListsAndAllocations(uint8 n, uint8 pick, bool sharing) public {
        vm.prank(admin);
        mmc.setMaxModelsPerOwner(16);
        uint256[] memory ids = new uint256[](16);
        for (uint256 i; i < 16; ++i) {
            // distance to the request grows with i, and ties go to the lower id: the top k
            // are the first k listed.
            ids[i] = _model(owner, cidFor(abi.encodePacked("m-", i)), uint32(3 + i), 3);
        }
        uint8 k = uint8(_bound(n, 1, 16));
        vm.prank(requester);
        uint256 allocId = mmc.allocateModel{value: k}(
            _request(k, sharing ? ModelsManager.Metric.Sharing : ModelsManager.Metric.Model)
        );
        for (uint256 i; i < 16; ++i) {
            vm.assertEq(uint256(mmc.allocState(allocId, ids[i])), i < k ? 1 : 0, "top k allocated");
        }
        vm.assertEq(uint256(mmc.allocState(allocId, 0)), 0, "id 0 never allocated");
        vm.assertEq(uint256(mmc.allocState(allocId + 1, ids[0])), 0, "unknown allocation");
        vm.assertEq(mmc.credits(owner), k, "owner paid per allocated model");
        uint256 j = _bound(pick, 0, k - 1);
        vm.prank(requester);
        mmc.updateModelRep(allocId, ids[j], 4);
        for (uint256 i; i < k; ++i) {
            vm.assertEq(uint256(mmc.allocState(allocId, ids[i])), i == j ? 2 : 1, "only that entry reviewed");
        }
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNotAllocated.selector, allocId, ids[j]));
        vm.prank(requester);
        mmc.updateModelRep(allocId, ids[j], 4);
        if (k < 16) {
            vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNotAllocated.selector, allocId, ids[k]));
            vm.prank(requester);
            mmc.updateModelRep(allocId, ids[k], 4);
        }
        (ModelsManager.ModelView memory m,,) = mmc.getModel(ids[j]);
        vm.assertEq(m.totalReview, 4, "Eq. 11 total of the reviewed model");
    }

    /// @dev Models are stored in their owner's list of each domain (one record per model, the
    /// list's length in its first): interleaved listings by two owners in two domains keep
    /// every model's owner, domain, attributes and totals, an allocation counts against the
    /// models it picked wherever they sit in their lists, and a review lands on that model.
    function testFuzz_modelRecords_ownerDomainLists(uint8 pattern, uint8 n, bool sharing) public {
        uint32 other = DOMAIN + 1;
        address[2] memory who = [_actor("lister-a"), _actor("lister-b")];
        _worker(who[0], (1 << DOMAIN) | (1 << other), 4);
        _worker(who[1], (1 << DOMAIN) | (1 << other), 4);
        vm.prank(admin);
        mmc.setMaxModelsPerOwner(16);
        uint256 count = _bound(n, 2, 12);
        uint256[] memory ids = new uint256[](count);
        uint256[] memory rankInDomain = new uint256[](count); // 1-based among DOMAIN's models
        uint256 inDomain = 0;
        for (uint256 i; i < count; ++i) {
            address w = who[(pattern >> (i % 8)) & 1];
            // the first model is in DOMAIN, so the allocation below has a candidate
            uint32 d = i == 0 || (pattern >> ((i + 3) % 8)) & 1 == 0 ? DOMAIN : other;
            string memory cid = cidFor(abi.encodePacked("rec-", i));
            _commit(w, cid);
            vm.prank(w);
            // distance to the request (3, 3) grows with i: DOMAIN's top k are its first k listed
            ids[i] = mmc.addModel(cid, "desc", d, _env(uint32(3 + i), uint32(3 + i % 2)));
            if (d == DOMAIN) rankInDomain[i] = ++inDomain;
        }
        uint8 k = 3;
        vm.prank(requester);
        uint256 allocId = mmc.allocateModel{value: k}(
            _request(k, sharing ? ModelsManager.Metric.Sharing : ModelsManager.Metric.Model)
        );
        uint256 last = 0; // the last model of DOMAIN that was allocated
        for (uint256 i; i < count; ++i) {
            (ModelsManager.ModelView memory m, string memory cid, uint32[] memory env) = mmc.getModel(ids[i]);
            bool allocated = rankInDomain[i] != 0 && rankInDomain[i] <= k;
            if (allocated) last = i;
            vm.assertEq(m.owner, who[(pattern >> (i % 8)) & 1], "owner");
            vm.assertEq(m.domain, rankInDomain[i] != 0 ? DOMAIN : other, "domain");
            vm.assertEq(m.envLen, 2, "attribute count");
            vm.assertEq(env[0], 3 + i, "attribute 0");
            vm.assertEq(env[1], 3 + i % 2, "attribute 1");
            vm.assertEq(keccak256(bytes(cid)), keccak256(bytes(cidFor(abi.encodePacked("rec-", i)))), "cid");
            vm.assertEq(m.allocCount, allocated ? 1 : 0, "Eq. 11 count of this model only");
            vm.assertEq(uint256(mmc.allocState(allocId, ids[i])), allocated ? 1 : 0, "allocation entry");
            vm.assertEq(m.totalReview, 0, "no review yet");
        }
        vm.prank(requester);
        mmc.updateModelRep(allocId, ids[last], 5);
        (ModelsManager.ModelView memory reviewed,,) = mmc.getModel(ids[last]);
        vm.assertEq(reviewed.totalReview, 5, "the review lands on the reviewed model");
        vm.assertEq(mmc.ownerRep(reviewed.owner).totalReview, 5, "and on its owner's Eq. 10 totals");
        (ModelsManager.ModelView memory none,,) = mmc.getModel(count + 1);
        vm.assertEq(none.owner, address(0), "an unknown id is no model");
    }

    // ------------------------------------------------------------------ withdraw

    function testFuzz_withdraw(uint80 price, address stranger_) public {
        _model(owner, cidFor("m-a"), 3, 3);
        uint256 p = _bound(price, 1, 1e24);
        vm.prank(requester);
        mmc.allocateModel{value: p}(_request(1, ModelsManager.Metric.Model));
        vm.assume(stranger_ != owner && mmc.credits(stranger_) == 0);
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNothingToWithdraw.selector, stranger_));
        vm.prank(stranger_);
        mmc.withdraw();
        vm.expectEmit(address(mmc));
        emit ModelsManager.Withdrawn(owner, p);
        vm.prank(owner);
        mmc.withdraw();
        vm.assertEq(owner.balance, p, "paid");
        vm.assertEq(address(mmc).balance, 0, "drained exactly");
        vm.expectRevert(abi.encodeWithSelector(ModelsManager.ModelsNothingToWithdraw.selector, owner));
        vm.prank(owner);
        mmc.withdraw();
    }

    /// An owner's earnings live in its Eq. 10 record: they must not move its counts, and a
    /// worker that also requests models withdraws earnings and refunds in one call, even
    /// after it was removed.
    function testFuzz_withdraw_earningsAndRefunds(uint80 price, uint8 n) public {
        _model(owner, cidFor("m-a"), 3, 3);
        uint256 p = _bound(price, 1, 1e24);
        uint8 k = uint8(_bound(n, 2, 16)); // owner2's request: only owner's one model fits
        vm.prank(requester);
        mmc.allocateModel{value: p}(_request(1, ModelsManager.Metric.Sharing));
        vm.prank(owner2);
        umc.addRequester();
        vm.prank(admin);
        umc.approveRequester(owner2);
        vm.deal(owner2, p * k);
        vm.prank(owner2);
        mmc.allocateModel{value: p * k}(_request(k, ModelsManager.Metric.Model));
        _model(owner2, cidFor("m-b"), 3, 3);
        vm.prank(owner);
        umc.addRequester();
        vm.prank(admin);
        umc.approveRequester(owner);
        vm.deal(owner, p * 3);
        vm.prank(owner); // owner's own model is skipped: one slot filled by owner2's, two refunded
        mmc.allocateModel{value: p * 3}(_request(3, ModelsManager.Metric.Model));
        ModelsManager.OwnerRep memory rep = mmc.ownerRep(owner);
        vm.assertEq(rep.allocCount, 2, "Eq. 10 count of owner: two allocations");
        vm.assertEq(rep.totalReview, 0, "no review");
        vm.assertEq(mmc.ownerRep(owner2).allocCount, 1, "Eq. 10 count of owner2");
        vm.assertEq(mmc.credits(owner), 2 * p + 2 * p, "earnings of two allocations + two refunded slots");
        vm.assertEq(mmc.credits(owner2), (k - 1) * p + p, "k - 1 refunded slots + one earning");
        vm.prank(owner);
        umc.removeWorker(owner);
        vm.expectEmit(address(mmc));
        emit ModelsManager.Withdrawn(owner, 4 * p);
        vm.prank(owner);
        mmc.withdraw();
        vm.assertEq(owner.balance, 4 * p, "earnings and refunds paid in one call");
        vm.assertEq(mmc.credits(owner), 0, "nothing left");
        vm.assertEq(mmc.ownerRep(owner).allocCount, 2, "withdrawing leaves Eq. 10 alone");
        vm.prank(owner2);
        mmc.withdraw();
        vm.assertEq(address(mmc).balance, 0, "drained exactly");
    }
}
