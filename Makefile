# The two entry points of README.md: `make demo` and `make test`. Both set everything up first.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEMO_OUT ?= runs/demo

.PHONY: setup demo train-demo test test-python test-benchmarks test-contracts lint bench-env bench-train bench-table \
	bench-ablations bench-recruitment bench-gas zoo clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	# torch first, pinned: pip takes the local CPU wheel of this machine kind (see shared/TOOLCHAIN.md)
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP)

contracts/node_modules/.installed: contracts/package-lock.json
	cd contracts && npm ci --no-audit --no-fund --loglevel=error
	touch $@

# Debian's Chromium for the browser tests (never a downloaded browser); CI runs as root.
/usr/bin/chromium:
	apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium

tests/ipfs-node/node_modules/.installed: tests/ipfs-node/package-lock.json
	cd tests/ipfs-node && npm ci --no-audit --no-fund --loglevel=error
	touch $@

# Foundry's cast (binary inside the npm package): the standard client the /rpc tests drive.
tests/foundry/node_modules/.installed: tests/foundry/package-lock.json
	cd tests/foundry && npm ci --no-audit --no-fund --loglevel=error
	touch $@

# The Swagger UI release /api/docs pins, served to its browser test in place of the CDN
# (--ignore-scripts: its @scarf/scarf dependency would report the install over the network).
tests/swagger-ui/node_modules/.installed: tests/swagger-ui/package-lock.json
	cd tests/swagger-ui && npm ci --ignore-scripts --no-audit --no-fund --loglevel=error
	touch $@

setup: $(STAMP) contracts/node_modules/.installed tests/ipfs-node/node_modules/.installed \
	tests/foundry/node_modules/.installed tests/swagger-ui/node_modules/.installed /usr/bin/chromium

# Main job (embedded default, nothing else to install): start the whole platform on this
# machine (chain with contracts, content store, broker, database, gateway, 3 worker daemons) and
# run the issue-4 scenario against it: register, submit, recruit, train, upload, review, share.
# Each run gets a fresh data directory (chain, jobs, store), $(DEMO_OUT)/platform-<time>.
demo: setup
	$(BIN)/drlaas demo-scenario --steps 50000 --data $(DEMO_OUT)/platform-$$(date +%Y%m%d-%H%M%S)

# The MDRL core alone: train the default preset briefly, then evaluate it against the baselines.
train-demo: setup
	rm -rf $(DEMO_OUT)/odmtl  # drlaas train refuses an --out that holds a run
	$(BIN)/drlaas train --preset odmtl-3a-10x10 --minutes 3 --seed 0 --out $(DEMO_OUT)/odmtl
	$(BIN)/drlaas eval --policy $(DEMO_OUT)/odmtl/model --episodes 500 --seed 1
	$(BIN)/drlaas eval --policy bayes --agents 3 --episodes 500 --seed 1

# forge (contracts/node_modules/.bin, npm ci) and slither (venv) for the contract checks.
FORGE_PATH := PATH=$(CURDIR)/contracts/node_modules/.bin:$(CURDIR)/$(BIN):$$PATH

# The contract checks and the Python tests run side by side (-j2; --output-sync prints each
# one's output whole when it ends): the contract checks are one solc-js compile and slither on
# one core for about eight minutes, which run in turn had left the other core idle.
test: setup
	$(MAKE) --no-print-directory -j2 --output-sync=target test-contracts test-python

test-python: setup
	$(BIN)/ruff check .
	$(BIN)/lint-imports  # layers of .importlinter: nothing imports upward
	# one process per core (-n auto), each file's tests in one process (--dist loadfile): a file's
	# module fixtures are built once and its own Redis database is used by one process only.
	# --durations: the slowest tests, because CI must stay under 30 minutes
	$(BIN)/python -m pytest -q -n auto --dist loadfile -m "not benchmark" --durations=20

# Tests that train for real to check a benchmark (benchmarks/medc/run.py end to end on tiny
# budgets, DC's learning-speed claim): kept out of CI's 30 minutes.
test-benchmarks: setup
	$(BIN)/python -m pytest -q -n auto --dist loadfile -m benchmark

# Foundry fuzz tests and invariants (foundry.toml: 10,000 calls per invariant), the per-function
# gas snapshot against the committed one (isolated transactions, thesis bounds asserted), and
# Slither with the zero-High / zero-unexplained-Medium gate.
test-contracts: setup
	# one compile of everything (forge test alone leaves GasTest out and snapshot compiles it
	# with the contracts again: 1.5 min more of solc-js)
	cd contracts && $(FORGE_PATH) forge build
	cd contracts && $(FORGE_PATH) forge test --no-match-contract GasTest
	cd contracts && $(FORGE_PATH) FORGE_SNAPSHOT_CHECK=true forge snapshot --isolate --match-contract GasTest --check
	$(FORGE_PATH) $(BIN)/python contracts/foundry/slither_gate.py

lint: setup
	$(BIN)/ruff check .
	$(BIN)/lint-imports

bench-env: setup
	$(BIN)/python benchmarks/env_throughput.py

bench-train: setup
	$(BIN)/python benchmarks/train_to_quality.py

bench-table: setup
	$(BIN)/python benchmarks/policy_table.py

bench-ablations: setup
	$(BIN)/python benchmarks/ablations.py

# Retrain every model of models/ (long: about 6 minutes each, the generalist 20; not in CI).
# Resumable: an interrupted run continues from runs/zoo/NAME/checkpoint.
zoo: setup
	$(BIN)/drlaas zoo train --models models --runs runs/zoo

bench-recruitment: setup
	$(BIN)/python benchmarks/recruitment/run.py

# Gas per function (forge, isolated transactions) next to thesis Table 7.5, with the ratio;
# rewrites contracts/.gas-snapshot and contracts/snapshots/GasTest.json.
bench-gas: setup
	cd contracts && $(FORGE_PATH) forge snapshot --isolate --match-contract GasTest
	$(BIN)/python benchmarks/gas_table.py

clean:
	rm -rf $(VENV) runs contracts/node_modules contracts/out contracts/cache tests/foundry/node_modules
