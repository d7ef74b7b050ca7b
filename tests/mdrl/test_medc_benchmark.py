"""The MEDC benchmark script end to end on a tiny budget: every guided method runs to its
held-out figures, the table and the kept-policy table print, and cached runs are reused (not
when they were run with another S of Eq. 9)."""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.benchmark  # `make test-benchmarks`: they train, three minutes in all
ROOT = Path(__file__).resolve().parents[2]
METHODS = ("sparse", "medc", "medc-anneal", "medc-credit", "il", "medc-il", "medc-mixed-credit",
           "il-mixed", "frl-mixed", "frl-biased", "medc-cae")
CAE = ROOT / "models" / "cae-10x10"
HORIZON = 2048  # steps per update (the presets' 8192 would make each FRL round 8 x 8192 steps)
STEPS = HORIZON  # one update per run


def bench(out: Path, *extra: str, methods: tuple[str, ...] = METHODS
          ) -> subprocess.CompletedProcess:
    cmd = [sys.executable, str(ROOT / "benchmarks" / "medc" / "run.py"), "--grid", "10",
           "--steps", str(STEPS), "--horizon", str(HORIZON), "--seeds", "0", "--tasks", "A3W3",
           "--methods", ",".join(methods),
           "--experts", "oracle,random", "--episodes", "10", "--eval-every", "1",
           "--cae", str(CAE), "--out", str(out), *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)


def test_the_benchmark_runs_every_guided_method_and_reuses_its_cache(tmp_path):
    first = bench(tmp_path)
    assert first.returncode == 0, first.stderr[-3000:]
    table = first.stdout
    for m in METHODS:
        assert f"| {m} | 1 |" in table, (m, table)
        run = json.loads((tmp_path / f"A3W3-10x10-{m}-s0-{STEPS}.json").read_text())
        # FRL stops at the end of a round of every user's update: at or past the budget
        assert run["steps"] == STEPS or m.startswith("frl") and run["steps"] >= STEPS
        assert run["horizon"] == HORIZON
        assert run["heldout"]["episodes"] == 10
        assert run["bonus"] == 50.0  # S of Eq. 9 (Table 4.1) unless --bonus
        assert run.get("local_updates") == (1 if m.startswith("frl") else None)
        # the kept policy is the curve's shortest time, judged on the held-out episodes
        assert run["best"]["curve_time"] == min(p["time"] for p in run["curve"])
        assert 0.0 <= run["best"]["heldout"]["success"] <= 1.0
    assert "Kept policy" in table and "kept policies:" in table
    # the experts on the task: the oracle expert's first choice is the oracle's action, so the
    # team following it takes the oracle's time on the same held-out episodes
    oracle_time = float(table.split("(oracle ")[1].split(" steps")[0])
    rows = {r.split(" | ")[0].strip("| "): r.split(" | ") for r in table.splitlines()
            if r.startswith(("| oracle |", "| random |"))}
    assert set(rows) == {"oracle", "random"}, table
    assert float(rows["oracle"][2].split()[0]) == oracle_time and rows["oracle"][5] == "1.00 |"
    assert float(rows["random"][2].split()[0]) > oracle_time
    assert "- medc ends at " in table and "x the fastest expert followed (oracle: " in table

    def card(method: str) -> dict:
        return json.loads((tmp_path / f"A3W3-10x10-{method}-s0-{STEPS}" / "model" / "model.json")
                          .read_text())

    # Fig. 5.8: MEDC and IL are given the same experts, the proper ones plus as many faulty
    def refs(method: str) -> list[str]:
        training = card(method)["training"]
        block = training["experts"] if "experts" in training else training["method"]
        return [e["ref"] for e in block["experts"]]

    assert refs("medc-mixed-credit") == refs("il-mixed") == ["oracle", "random", "random",
                                                             "biased:8"]
    assert refs("medc") == refs("il") == refs("medc-cae") == ["oracle", "random"]
    # medc-cae: the learner sees the walls CAE's embedding, the experts keep their own inputs
    assert card("medc-cae")["observation"]["walls_embedding"] == str(CAE)
    assert "walls_embedding" not in card("medc")["observation"]
    assert "medc with the walls CAE" in table
    assert "medc-mixed-credit vs IL-MIXED: shorter mean episodes at" in table
    assert "medc-mixed-credit vs FRL-MIXED: shorter mean episodes at" in table
    # FRL in Fig. 5.8: 3 of the other 7 users send random, biased and malicious weights
    frl = card("frl-mixed")["training"]["method"]
    assert sorted(frl["faulty_users"].values()) == ["biased:8", "malicious", "random"]
    assert "A3W3" not in frl["faulty_users"] and set(frl["faulty_users"]) < set(frl["users"])
    # frl-biased: frl-mixed's biased user alone, the same user, nobody else faulty
    one = card("frl-biased")["training"]["method"]
    assert one["faulty_users"] == {u: k for u, k in frl["faulty_users"].items()
                                   if k.startswith("biased:")} and len(one["faulty_users"]) == 1
    assert "medc-mixed-credit vs FRL-BIASED: shorter mean episodes at" in table
    again = bench(tmp_path)  # every run is cached: nothing trains, the same table prints
    assert again.returncode == 0, again.stderr[-3000:]
    assert again.stdout == first.stdout
    assert again.stderr.count("min)") == len(METHODS)  # one line per cached run
    # runs cached with another S of Eq. 9 are refused, not mixed into the table
    other = bench(tmp_path, "--bonus", "200")
    assert other.returncode != 0 and "S = 50" in other.stderr and "another --out" in other.stderr
    # nor runs of FRL averaging every 1 update when every 2 is asked
    k2 = bench(tmp_path, "--frl-local-updates", "2", "--eval-every", "2")
    assert k2.returncode != 0 and "every 1 local update(s), not 2" in k2.stderr, k2.stderr
    # nor runs of another number of steps per update
    h = bench(tmp_path, "--horizon", str(HORIZON // 2))
    assert h.returncode != 0 and f"{HORIZON} steps per update, not {HORIZON // 2}" in h.stderr


def test_frl_averaging_every_k_updates_is_evaluated_at_the_same_steps(tmp_path):
    """--frl-local-updates K: FRL averages every K updates of each user, is evaluated every
    --eval-every updates as the other methods are (K must divide it), and records K."""
    bad = bench(tmp_path, "--frl-local-updates", "2", methods=("frl",))  # --eval-every 1
    assert bad.returncode == 2 and "must divide --eval-every" in bad.stderr
    steps = 3 * HORIZON  # 3 updates: a round of 2, then 1 (cut short)
    done = bench(tmp_path, "--frl-local-updates", "2", "--eval-every", "2", "--steps", str(steps),
                 methods=("frl",))
    assert done.returncode == 0, done.stderr[-3000:]
    run = json.loads((tmp_path / f"A3W3-10x10-frl-s0-{steps}.json").read_text())
    assert run["local_updates"] == 2 and run["steps"] == steps
    # evaluated after 2 updates (every --eval-every 2) and at the end, as a lone trainer is
    assert [p["step"] for p in run["curve"]] == [2 * HORIZON, steps]
    method = json.loads((tmp_path / f"A3W3-10x10-frl-s0-{steps}" / "model" / "model.json")
                        .read_text())["training"]["method"]
    assert method["local_updates"] == 2 and method["rounds"] == 2
    assert "frl averaging every 2 local updates" in done.stdout


def test_the_review_keeps_the_fastest_experts_on_episodes_of_its_own(tmp_path):
    """--review K: each candidate followed by the team on review episodes of their own (not the
    held-out ones); the K shortest are kept, in their given order, with equal QoS, and the
    runs learn from those only."""
    refused = [bench(tmp_path, *args, methods=("medc",)) for args in (
        ("--experts", "random,oracle", "--review", "3"),
        ("--review", "1", "--tasks", "A3W2,A3W3"),
        ("--review", "1", "--qos", "2,1"))]
    assert [r.returncode for r in refused] == [2, 2, 2]
    assert "--review must be in 1..2" in refused[0].stderr
    assert "one task" in refused[1].stderr and "drop --qos" in refused[2].stderr
    done = bench(tmp_path, "--experts", "random,biased:0,oracle", "--review", "2",
                 "--review-episodes", "12", methods=("medc",))
    assert done.returncode == 0, done.stderr[-3000:]
    run = json.loads((tmp_path / f"A3W3-10x10-medc-s0-{STEPS}.json").read_text())
    assert run["experts"] == ["random", "oracle"] and run["qos"] == []  # biased:0 only idles
    card = json.loads((tmp_path / f"A3W3-10x10-medc-s0-{STEPS}" / "model" / "model.json")
                      .read_text())["training"]
    block = card["experts"] if "experts" in card else card["method"]
    assert [e["ref"] for e in block["experts"]] == ["random", "oracle"]
    rows = {line.split(" | ")[0].strip("| "): line.split(" | ")
            for line in done.stdout.split("### The review")[1].splitlines()[3:6]}
    assert [rows[r][1] for r in ("random", "biased:0", "oracle")] == ["yes", "no", "yes"]
    review = json.loads(next(tmp_path.glob("A3W3-10x10-review2-oracle-12.json")).read_text())
    heldout = json.loads(next(tmp_path.glob("A3W3-10x10-expert1-oracle-10.json")).read_text())
    assert review["heldout"]["episodes"] == 12 and review["seed"] != heldout["seed"]
    assert review["heldout"]["oracle_time"] == review["heldout"]["time"]  # oracle = oracle


def _figures(run: dict) -> dict:
    """A cached run without its wall-clock (the only thing sharing the machine changes)."""
    return {"heldout": run["heldout"], "steps": run["steps"],
            "curve": [{k: v for k, v in p.items() if k != "wall"} for p in run["curve"]]}


def test_runs_in_parallel_processes_give_the_figures_of_runs_in_turn(tmp_path):
    """--jobs 2: the missing runs train two at a time in processes of their own, each with its
    log; every run's curve and held-out figures are those of the same run trained in turn."""
    methods, seeds = ("sparse", "medc"), ("--seeds", "0,1")
    parallel = bench(tmp_path / "jobs", *seeds, "--jobs", "2", methods=methods)
    assert parallel.returncode == 0, parallel.stderr[-3000:]
    in_turn = bench(tmp_path / "turn", *seeds, methods=methods)
    assert in_turn.returncode == 0, in_turn.stderr[-3000:]
    for m in methods:
        assert f"| {m} | 2 |" in parallel.stdout, parallel.stdout
        for s in (0, 1):
            name = f"A3W3-10x10-{m}-s{s}-{STEPS}"
            a, b = (json.loads((tmp_path / d / f"{name}.json").read_text())
                    for d in ("jobs", "turn"))
            assert _figures(a) == _figures(b), name
            assert f"A3W3 {m} seed {s}: started" in parallel.stderr
            assert f"A3W3 {m} seed {s}: done in " in parallel.stderr
            assert "time" in (tmp_path / "jobs" / "logs" / f"A3W3-{m}-s{s}.log").read_text()
    assert not (tmp_path / "turn" / "logs").exists()  # in turn: one process, no logs


def test_a_failed_parallel_run_names_itself_and_its_log_and_spares_the_others(tmp_path):
    """One run failing (its expert does not exist) stops the benchmark with its name and log;
    the runs that could train are cached, so the next call trains only what is missing."""
    missing = tmp_path / "no-such-expert"
    r = bench(tmp_path, "--experts", f"oracle,{missing}", "--jobs", "2",
              methods=("sparse", "medc"))
    assert r.returncode != 0
    log = tmp_path / "logs" / "A3W3-medc-s0.log"
    assert "1 of 2 run(s) failed: A3W3 medc seed 0" in r.stderr and str(log) in r.stderr
    assert str(missing) in log.read_text()  # the child's own error names the expert
    assert (tmp_path / f"A3W3-10x10-sparse-s0-{STEPS}.json").is_file()
    assert not (tmp_path / f"A3W3-10x10-medc-s0-{STEPS}.json").exists()
    assert "A3W3 sparse seed 0: done in " in r.stderr and "A3W3 medc seed 0: done" not in r.stderr
    bad = bench(tmp_path, "--jobs", "0", methods=("sparse",))
    assert bad.returncode == 2 and "--jobs must be >= 1, got 0" in bad.stderr


def test_a_killed_parallel_benchmark_stops_its_runs_and_starts_no_more(tmp_path):
    """SIGTERM to the benchmark with --jobs 2: both running children are stopped with it (no
    orphan goes on training), the third run never starts, and the exit status says killed."""
    cmd = [sys.executable, str(ROOT / "benchmarks" / "medc" / "run.py"), "--grid", "10",
           "--steps", "50000000", "--seeds", "0,1,2", "--tasks", "A3W3", "--methods", "sparse",
           "--experts", "oracle", "--out", str(tmp_path), "--jobs", "2"]
    parent = subprocess.Popen(cmd, cwd=ROOT, stderr=subprocess.PIPE, text=True)
    started = [parent.stderr.readline() for _ in range(2)]
    assert all(": started, log " in line for line in started), started
    time.sleep(2)  # both children are training
    parent.send_signal(signal.SIGTERM)
    assert parent.wait(timeout=60) == 128 + signal.SIGTERM
    parent.stderr.close()
    left = subprocess.run(["pgrep", "-f", str(tmp_path)], capture_output=True, text=True)
    assert left.stdout == "", f"children still running: {left.stdout}"
    assert sorted(p.name for p in (tmp_path / "logs").iterdir()) == [
        "A3W3-sparse-s0.log", "A3W3-sparse-s1.log"]
