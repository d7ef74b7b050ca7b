"""Gas per contract function (forge, isolated transactions) next to thesis Table 7.5.

Reads contracts/snapshots/GasTest.json, written by contracts/test/Gas.t.sol under
`forge test --isolate` (`make bench-gas` runs it first), and prints function, thesis figure,
ours and the ratio. Figures are transaction gas (a receipt's gasUsed) in the scenario of
backend/chain/gas.py: 50 workers with one model each in the domain, 5 workers/models per
request.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from backend.chain.gas import THESIS_TABLE_7_5

SNAPSHOT = Path(__file__).resolve().parents[1] / "contracts" / "snapshots" / "GasTest.json"


def table(snapshot: dict[str, str]) -> list[tuple[str, int | None, int, float | None]]:
    """Rows (function, thesis, ours, ours / thesis): Table 7.5 functions first, in its order."""
    ours = {k: int(v) for k, v in snapshot.items()}
    names = [n for n in THESIS_TABLE_7_5 if n in ours] + sorted(set(ours) - set(THESIS_TABLE_7_5))
    rows = []
    for name in names:
        thesis = THESIS_TABLE_7_5.get(name)
        rows.append((name, thesis, ours[name], round(ours[name] / thesis, 3) if thesis else None))
    return rows


def main() -> int:
    if not SNAPSHOT.exists():
        print(f"{SNAPSHOT} missing: run `make bench-gas`", file=sys.stderr)
        return 1
    rows = table(json.loads(SNAPSHOT.read_text()))
    print(f"{'function':32} {'thesis':>10} {'ours':>10} {'ratio':>7}")
    for name, thesis, ours, ratio in rows:
        t = f"{thesis:,}" if thesis else "-"
        r = f"{ratio:.2f}" if ratio is not None else "-"
        print(f"{name:32} {t:>10} {ours:>10,} {r:>7}")
    above = [n for n, t, o, _ in rows if t and o > t]
    print(
        f"\n{len(above)} of {sum(1 for r in rows if r[1])} Table 7.5 functions above the thesis: "
        + (", ".join(above) or "none")
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
