"""Accuracy of Sobol' indices on Ishigami: errors, bootstrap half-widths and their coverage.

Second-order designs (runs N(2D + 2)) for N = 64 .. 4096, seeds SeedSequence(0 .. repeats-1),
default resamples and confidence, in-process with the analytic solver. Errors are absolute,
pooled over the three inputs and the seeds; the half-width is the mean reported ``*_conf``;
coverage is the fraction of S1 and ST intervals holding the exact index. The table goes to
docs/sobol.md (between its ``sobol-accuracy`` markers) and to BENCHMARKS.md.

    python benchmarks/sobol_accuracy.py [--repeats 20]
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._record import ROOT, write_section  # noqa: E402
from solvers.analytic import AnalyticSolver  # noqa: E402
from uqflow.inputs import InputSpace, RandomInput  # noqa: E402
from uqflow.methods import get_method  # noqa: E402
from uqflow.realization import evaluate_design  # noqa: E402

# Ishigami a = 7, b = 0.1: S1 = [V1, V2, 0] / V, ST = [V1 + V13, V2, V13] / V.
A, B = 7.0, 0.1
V1 = 0.5 * (1 + B * math.pi**4 / 5) ** 2
V2 = A**2 / 8
V13 = B**2 * math.pi**8 * (1 / 18 - 1 / 50)
V = V1 + V2 + V13
S1 = np.array([V1, V2, 0.0]) / V
ST = np.array([V1 + V13, V2, V13]) / V
S13 = V13 / V
SIZES = (64, 256, 1024, 4096)


def one(n, seed, solver, space):
    method = get_method("sobol")(samples=n, second_order=True)
    design = method.plan(space, None, np.random.SeedSequence(seed))
    stats = method.analyze(design, evaluate_design(solver, design))
    si = stats["y_sobol"]
    s1, st = si.sel(sobol_index="S1").values, si.sel(sobol_index="ST").values
    s1c, stc = si.sel(sobol_index="S1_conf").values, si.sel(sobol_index="ST_conf").values
    s13 = float(stats["y_sobol2"].sel(sobol2_index="S2").values[0, 2])
    covered = np.concatenate([np.abs(s1 - S1) <= s1c, np.abs(st - ST) <= stc])
    return (design.sizes["realization"], np.abs(s1 - S1), np.abs(st - ST), abs(s13 - S13),
            s1c, stc, covered)


def measure(repeats):
    space = InputSpace([RandomInput.from_spec(dict(name=f"x{i}", distribution="uniform",
                                                   lower=-math.pi, upper=math.pi))
                        for i in (1, 2, 3)])
    solver = AnalyticSolver.from_scene({"model": "ishigami", "a": A, "b": B})
    rows = []
    for n in SIZES:
        res = [one(n, s, solver, space) for s in range(repeats)]
        e1 = np.concatenate([r[1] for r in res])
        et = np.concatenate([r[2] for r in res])
        e13 = np.array([r[3] for r in res])
        rows.append(dict(n=n, first=n * 5, second=res[0][0], e1=e1, et=et, e13=e13,
                         h1=np.mean([r[4] for r in res]), ht=np.mean([r[5] for r in res]),
                         coverage=np.mean(np.concatenate([r[6] for r in res]))))
        print(f"N={n}: S1 {e1.mean():.2g}/{e1.max():.2g}, ST {et.mean():.2g}/{et.max():.2g}, "
              f"coverage {rows[-1]['coverage']:.3f}", flush=True)
    return rows


def _g(x) -> str:
    return f"{x:.2g}" if x < 0.01 else f"{x:.3f}"


def table(rows) -> str:
    lines = ["| N | runs (D+2) | runs (2D+2) | S1 mean / max error | ST mean / max error | "
             "S13 mean / max error | mean half-width S1 / ST | coverage |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['n']} | {r['first']:,} | {r['second']:,} | "
            f"{_g(r['e1'].mean())} / {_g(r['e1'].max())} | "
            f"{_g(r['et'].mean())} / {_g(r['et'].max())} | "
            f"{_g(r['e13'].mean())} / {_g(r['e13'].max())} | "
            f"{_g(r['h1'])} / {_g(r['ht'])} | {100 * r['coverage']:.1f} % |")
    return "\n".join(lines).replace(",", " ")


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    text = table(measure(args.repeats))
    print(text)
    doc = ROOT / "docs" / "sobol.md"
    pattern = re.compile(r"(<!-- begin sobol-accuracy -->\n).*?(<!-- end sobol-accuracy -->)",
                         re.S)
    source = doc.read_text()
    if pattern.search(source):
        doc.write_text(pattern.sub(lambda m: m.group(1) + text + "\n" + m.group(2), source))
    write_section("sobol-accuracy", "Sobol' indices: accuracy on Ishigami",
                  f"Benchmark figures (redo with the command above): {args.repeats} seeds per "
                  f"N, second-order designs, default resamples and confidence; errors "
                  f"absolute, pooled over the inputs and seeds.\n\n{text}")


if __name__ == "__main__":
    main()
