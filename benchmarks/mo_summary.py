"""Tables of the multi-objective benchmarks (means over seeds) from their JSON-lines results.

    python benchmarks/mo_summary.py
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def _rows(name: str) -> list[dict]:
    path = RESULTS / name
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def _stat(values: list[float]) -> str:
    a = np.asarray(values, np.float64)
    return f"{a.mean():.4f} ± {a.std():.4f}" if len(a) > 1 else f"{a.mean():.4f}"


def zdt(name: str, true_hv: float) -> None:
    rows = _rows(name)
    if not rows:
        return
    print(f"\n{name}: mean ± std over seeds (hypervolume / true front's {true_hv:.4f})")
    print("| algorithm | library | seeds | hypervolume | ratio to true | loop s | wall s (build+compile+loop) | process s |")
    print("|---|---|---|---|---|---|---|---|")
    for alg in ("nsga2", "spea2"):
        for impl in ("qdrl", "pymoo"):
            r = [x for x in rows if x["algorithm"] == alg and x["impl"] == impl]
            if r:
                hv = [x["hypervolume"] for x in r]
                print(f"| {alg} | {impl} | {len(r)} | {_stat(hv)} | {np.mean(hv) / true_hv:.4f} | "
                      f"{np.mean([x['run_s'] for x in r]):.2f} | {np.mean([x['wall_s'] for x in r]):.2f} | "
                      f"{np.mean([x['process_s'] for x in r]):.2f} |")


def mome() -> None:
    rows = _rows("mome_rastrigin_vs_qdax.jsonl")
    if not rows:
        return
    print("\nmome_rastrigin_vs_qdax.jsonl: mean ± std over seeds")
    print("| implementation | seeds | MOQD score (-1500) | global HV (-1500) | MOQD (-150) | solutions | loop s | compile s |")
    print("|---|---|---|---|---|---|---|---|")
    for impl in ("qdrl", "qdrl_index", "qdax"):
        r = [x for x in rows if x["impl"] == impl]
        if r:
            print(f"| {impl} | {len(r)} | {_stat([x['moqd_score_reachable'] for x in r])} | "
                  f"{_stat([x['global_hypervolume_reachable'] for x in r])} | "
                  f"{np.mean([x['moqd_score_qdax'] for x in r]):.1f} | {np.mean([x['num_solutions'] for x in r]):.0f} | "
                  f"{np.mean([x['run_s'] for x in r]):.1f} | {np.mean([x['compile_s'] for x in r]):.1f} |")


if __name__ == "__main__":
    zdt("mo_zdt1_vs_pymoo.jsonl", 2 / 3)
    zdt("mo_dtlz2_vs_pymoo.jsonl", 1 - np.pi / 6)
    zdt("mo_zdt1_40k_vs_pymoo.jsonl", 2 / 3)
    zdt("mo_zdt1_redraws0_vs_pymoo.jsonl", 2 / 3)
    zdt("mo_zdt1_pruning_vs_pymoo.jsonl", 2 / 3)
    zdt("mo_zdt1_spea2_30seeds_vs_pymoo.jsonl", 2 / 3)
    zdt("mo_dtlz2_pruning_vs_pymoo.jsonl", 1 - np.pi / 6)
    mome()
