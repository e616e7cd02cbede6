"""Accuracy bought per solver run: Monte Carlo rules, Taylor and Sobol on exact models.

For every method and budget the error against the exact answer is the root mean square over
independent repetitions (different seeds), so a line is the typical error a user gets, not one
lucky draw. Beside it, for Monte Carlo, the standard error the method *reported* (RMS over the
seeds) and how often its 95 % interval held the exact mean: an honest error bar is about the
size of the actual error and covers about 95 % of the time. Runs in-process (the solver is
closed-form): this measures accuracy, not speed.

    python benchmarks/accuracy_vs_runs.py [--repeats 20]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._record import FIGURES, write_section  # noqa: E402
from solvers.analytic import AnalyticSolver  # noqa: E402
from uqflow.inputs import InputSpace, RandomInput  # noqa: E402
from uqflow.methods import get_method  # noqa: E402
from uqflow.realization import evaluate_design  # noqa: E402

PI = math.pi


def ishigami():
    space = InputSpace([RandomInput.from_spec(dict(name=f"x{i}", distribution="uniform",
                                                   lower=-PI, upper=PI)) for i in (1, 2, 3)])
    return ("Ishigami (a=7, b=0.1), X_i ~ U(-pi, pi)", AnalyticSolver.from_scene(
        {"model": "ishigami"}), space, 3.5, 13.844587940719254)


def power_law(cv=0.15, p=3.0):
    space = InputSpace([RandomInput.from_spec(dict(name="x", distribution="lognormal",
                                                   mean=1.0, cv=cv))])
    mean = (1 + cv * cv) ** (p * (p - 1) / 2)
    second = (1 + cv * cv) ** (2 * p * (2 * p - 1) / 2)
    return (f"power law X^{p:g}, X lognormal C.V. {cv:g}", AnalyticSolver.from_scene(
        {"model": "power", "p": p}), space, mean, second - mean**2)


def errors(method, solver, space, exact_mean, exact_var, seed):
    """Runs, relative errors of mean and variance, and (Monte Carlo) the reported relative
    standard error, the i.i.d. formula's one and whether the interval held the exact mean."""
    design = method.plan(space, None, np.random.SeedSequence(seed))
    stats = method.analyze(design, evaluate_design(solver, design))
    y = stats["y"]
    mean = float(y.sel(statistic="mean"))
    var = float(y.sel(statistic="variance"))
    reported = iid = covered = np.nan
    if "ci_low" in y["statistic"].values:
        reported = float(y.sel(statistic="stderr")) / abs(exact_mean)
        iid = float(y.sel(statistic="std")) / math.sqrt(stats.attrs["samples_ok"]) / abs(
            exact_mean)
        covered = float(y.sel(statistic="ci_low")) <= exact_mean <= float(
            y.sel(statistic="ci_high"))
    return (design.sizes["realization"], abs(mean - exact_mean) / abs(exact_mean),
            abs(var - exact_var) / exact_var, reported, iid, covered)


def measure(repeats: int):
    rows = []
    for problem in (ishigami(), power_law()):
        title, solver, space, m, v = problem
        for rule in ("random", "lhs", "sobol", "halton"):
            for n in (64, 256, 1024, 4096):
                method = get_method("monte-carlo")(samples=n, rule=rule)
                errs = np.array([errors(method, solver, space, m, v, s)
                                 for s in range(repeats)])
                rows.append((title, f"monte-carlo/{rule}", int(errs[0, 0]),
                             _rms(errs[:, 1]), _rms(errs[:, 2]), _rms(errs[:, 3]),
                             _rms(errs[:, 4]), int(errs[:, 5].sum())))
        for n in (64, 256, 1024, 4096):
            method = get_method("sobol")(samples=n, resamples=10)
            errs = np.array([errors(method, solver, space, m, v, s)
                             for s in range(max(repeats // 4, 3))])
            rows.append((title, "sobol", int(errs[0, 0]), _rms(errs[:, 1]), _rms(errs[:, 2]),
                         np.nan, np.nan, None))
        for order in (1, 2):
            method = get_method("taylor")(order=order, step_check=False)
            runs, em, ev, *_ = errors(method, solver, space, m, v, 0)
            rows.append((title, f"taylor/order {order}", runs, em, ev, np.nan, np.nan, None))
    return rows


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def figure(rows, path: Path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    problems = list(dict.fromkeys(r[0] for r in rows))
    fig, axes = plt.subplots(2, len(problems), figsize=(6 * len(problems), 8), squeeze=False)
    for col, problem in enumerate(problems):
        for row, (label, k) in enumerate((("mean", 3), ("variance", 4))):
            ax = axes[row, col]
            for method in dict.fromkeys(r[1] for r in rows if r[0] == problem):
                pts = [(r[2], max(r[k], 1e-17)) for r in rows if r[0] == problem and
                       r[1] == method]
                x, y = zip(*pts)
                style = "o" if method.startswith("taylor") else "o-"
                line, = ax.loglog(x, y, style, label=method)
                if k == 3 and method.startswith("monte-carlo"):
                    reported = [r[5] for r in rows if r[0] == problem and r[1] == method]
                    ax.loglog(x, reported, "--", color=line.get_color(), linewidth=1,
                              label=f"{method}: reported stderr")
            ax.set_xlabel("solver runs")
            ax.set_ylabel(f"relative error of the {label} (RMS)")
            ax.set_title(problem, fontsize=9)
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _e(x) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.2e}"


def record(rows, repeats):
    fig_path = FIGURES / "accuracy_vs_runs.png"
    figure(rows, fig_path)
    lines = ["| problem | method | solver runs | rel. error of mean | reported rel. stderr | "
             "i.i.d. formula | 95 % interval covered | rel. error of variance |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    lines += [f"| {r[0]} | {r[1]} | {r[2]} | {_e(r[3])} | {_e(r[5])} | {_e(r[6])} | "
              f"{'-' if r[7] is None else f'{r[7]} of {repeats}'} | {_e(r[4])} |"
              for r in rows]
    rel = 1 / math.sqrt(2 * repeats)
    band = 4 * math.sqrt(0.95 * 0.05 / repeats) * repeats
    body = (f"Benchmark figures (redo with the command above). Root-mean-square over "
            f"{repeats} seeds (Sobol indices: {max(repeats // 4, 3)}; Taylor is "
            f"deterministic: one run), so each RMS figure carries a sampling error of its "
            f"own of about 1/sqrt(2 x {repeats}) = {100 * rel:.0f} %. Sobol' indices' runs "
            f"are N(D+2) for base sample N. *Reported rel. stderr*: the standard error "
            f"Monte Carlo reported, RMS over the seeds, divided by the exact mean; *i.i.d. "
            f"formula*: s/sqrt(n) on the same points; *95 % interval covered*: in how many "
            f"of the {repeats} studies the reported interval held the exact mean (for an "
            f"honest interval a binomial count, 95 % of {repeats} +- {band:.1f} at 4 "
            f"sigma). Sobol' and Halton use randomized QMC with 8 replicates "
            f"(docs/inputs.md, \"Error of the mean\").\n\n" + "\n".join(lines) +
            "\n\n![error against solver runs](docs/figures/accuracy_vs_runs.png)\n\n"
            "What it shows: random Monte Carlo falls like runs^-1/2 whatever the "
            "model, and its reported error matches its actual error; LHS falls faster on "
            "these smooth integrands while its reported (i.i.d.) error stays the "
            "conservative runs^-1/2 one. For scrambled Sobol' and Halton the reported "
            "error is the spread of 8 replicate means: it follows the actual error down "
            "(it is not the i.i.d. formula, which overstates it by the factor in the "
            "columns beside it), and the intervals cover at about the stated rate. "
            "Taylor buys the mean of the smooth power law cheaply but its first-order "
            "variance is far off; on Ishigami, far from quadratic over its input range, "
            "Taylor is wrong by 100 % or more: the case for checking a Taylor answer "
            "against Monte Carlo once.")
    write_section("accuracy-vs-runs", "Accuracy against solver runs", body)


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    rows = measure(args.repeats)
    for r in rows:
        print(f"{r[0][:30]:30} {r[1]:22} {r[2]:7d} {r[3]:.2e} {r[4]:.2e} {_e(r[5])} "
              f"{_e(r[6])} {r[7]}")
    record(rows, args.repeats)


if __name__ == "__main__":
    main()
