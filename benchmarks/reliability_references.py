"""Reference failure probabilities of the reliability benchmark's problems, written to
``benchmarks/reliability_references.json``.

Every problem has an exact value (a closed formula, or for the four-branch system one smooth
integral by adaptive quadrature: ``reliability_problems.py`` derives both). As an independent
check of each margin, plain Monte Carlo in numpy with 10^8 samples (in chunks of 10^7, seeded)
is stored beside the exact value with its standard error sqrt(p (1 - p) / n), except for
``linear_100``: at p = 1e-6, 10^8 samples would see ~100 failures (a 10 % error) for 10^10
normal draws; its formula needs no check beyond tests/test_reliability_problems.py.

    python benchmarks/reliability_references.py             # 10^8 samples per problem
    python benchmarks/reliability_references.py --samples 1e6
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from reliability_problems import PROBLEMS, four_branch_exact  # noqa: E402

OUTPUT = Path(__file__).resolve().parent / "reliability_references.json"
CHUNK = 10**7
NO_MONTE_CARLO = ("linear_100",)

HOW = {
    "r_minus_s": "Phi(-sqrt 2): R - S ~ N(2, 2)",
    "four_branch_6": "2 Phi(-k/2) + integral_{|b| < k/2} phi(b) 2 Phi(-(3 + b^2/5)) db "
                     "(scipy quad, epsrel 1e-13)",
    "four_branch_7": "2 Phi(-k/2) + integral_{|b| < k/2} phi(b) 2 Phi(-(3 + b^2/5)) db "
                     "(scipy quad, epsrel 1e-13)",
    "linear_100": "Phi(-4.75): sum(u)/10 ~ N(0, 1)",
    "two_design_points": "Phi(-3) + Phi(-3.2): two disjoint half-planes",
    "correlated_lognormals": "Phi(-beta), beta = a.mu / sqrt(a' S R S a): ln C - ln L - ln M "
                             "is normal",
}


def monte_carlo(problem, samples: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    failures, done = 0, 0
    while done < samples:
        n = min(CHUNK, samples - done)
        u = rng.standard_normal((n, problem.dimension))
        failures += int(np.count_nonzero(problem.margin_u(u) <= 0))
        done += n
    p = failures / samples
    return {"samples": samples, "seed": seed, "failures": failures, "p_f": p,
            "stderr": math.sqrt(p * (1 - p) / samples)}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=float, default=1e8)
    ap.add_argument("--output", type=Path, default=OUTPUT)
    args = ap.parse_args(argv)
    references = {}
    for seed, (name, problem) in enumerate(PROBLEMS.items()):
        entry = {"title": problem.title, "p_f": problem.exact(), "how": HOW[name]}
        if name.startswith("four_branch"):
            entry["quadrature_error_estimate"] = four_branch_exact(
                float(name.rsplit("_", 1)[1]))[1]
        if name not in NO_MONTE_CARLO:
            entry["monte_carlo"] = monte_carlo(problem, int(args.samples), 2026 + seed)
            mc = entry["monte_carlo"]
            entry["monte_carlo"]["z"] = (mc["p_f"] - entry["p_f"]) / mc["stderr"]
        references[name] = entry
        print(name, json.dumps(entry), flush=True)
    args.output.write_text(json.dumps(references, indent=1) + "\n")
    return references


if __name__ == "__main__":
    main()
