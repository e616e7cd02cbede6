"""One run or 2n+1: what the seed's frozen-state method (`taylor-local`) misses against the
whole-solver derivatives (`taylor`) and a Monte Carlo reference, over whole time series.

Both seed examples on the small contact-explosion scenes at resolution 0.5 (10 mm cells,
8,400 particles): example 2 (thin plate, Johnson-Cook A, B, C, n, m normal, C.V. 0.10 and
0.15; flow_stress, flow_stress_total_rate, S11, S22 and, without local derivatives,
plastic_strain at H, I, G, K) and example 1 (thick plate, Mie-Grueneisen S1, gamma0, a normal,
C.V. 0.01, 0.05 and 0.15; pressure at E, F). Per case three studies: `taylor-local` (1 run),
`taylor` (2n+1 runs; thin step = 1 std as the shipped study, thick the default 0.1 std) and
the reference, Monte Carlo with `control = "taylor"` on 64 = 8 x 8 scrambled Sobol' points
(seed 1 for every case: the same normal draws at every C.V.), 2 dask workers, which reports
the standard errors of its mean and variance with 7 degrees of freedom.

    python benchmarks/smpm_local_vs_global.py [--scratch DIR] [--reuse]

Result files go to the scratch folder (default /tmp/smpm_local_vs_global), never into the
repository; ``--reuse`` analyses existing ones. Writes the figures into docs/figures/ and the
section "smpm-local-vs-global" of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.stats as sps
import xarray as xr

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import FIGURES, write_section  # noqa: E402
from _studies import write_normal_study, write_scene_variant  # noqa: E402

from solvers.mpm.materials import johnson_cook  # noqa: E402

RESOLUTION = 0.5
MC_SAMPLES, MC_REPLICATES, MC_SEED = 64, 8, 1
#: Two-sided 99.73 % quantile of Student's t with 7 degrees of freedom (8 replicates): the
#: level "3 standard errors" has for a normal error (docs/mpm_scenes.md).
T7 = float(sps.t.ppf(0.5 + 0.9973 / 2, MC_REPLICATES - 1))

# the study means: the 4340 defaults of the flow-stress parameters (seed Table 5)
JC = {name.removeprefix("jc."): johnson_cook.PARAMETERS[name]
      for name in johnson_cook.DIFFERENTIABLE_PARAMETERS}
EOS = {"S1": 1.49, "gamma0": 2.17, "a": 0.46}


@dataclass(frozen=True)
class Case:
    example: str          # "thin" (example 2) or "thick" (example 1)
    cv: float

    @property
    def key(self) -> str:
        return f"{self.example}_cv{self.cv:.2f}"

    @property
    def inputs(self) -> dict[str, float]:
        return {f"steel.jc.{k}": v for k, v in JC.items()} if self.example == "thin" \
            else {f"steel.eos.{k}": v for k, v in EOS.items()}

    @property
    def local_outputs(self) -> list[str]:
        return ["flow_stress", "flow_stress_total_rate", "S11", "S22"] \
            if self.example == "thin" else ["pressure"]

    @property
    def history_outputs(self) -> list[str]:
        """Outputs without a local derivative, run by `taylor` and Monte Carlo only."""
        return ["plastic_strain"] if self.example == "thin" else []

    @property
    def step(self) -> float:
        return 1.0 if self.example == "thin" else 0.1


CASES = [Case("thin", 0.10), Case("thin", 0.15),
         Case("thick", 0.01), Case("thick", 0.05), Case("thick", 0.15)]
METHODS = ("taylor_local", "taylor", "reference")


def write_scene(example: str, folder: Path) -> Path:
    """The shipped small scene at RESOLUTION with the outputs the comparison needs."""
    outputs = ["flow_stress", "flow_stress_total_rate", "S11", "S22", "plastic_strain"] \
        if example == "thin" else ["pressure"]
    return write_scene_variant(f"mpm_contact_{example}_small.toml",
                               folder / f"scene_{example}.toml", resolution=RESOLUTION,
                               outputs=outputs)

def write_study(case: Case, method: str, folder: Path) -> Path:
    outputs = case.local_outputs + ([] if method == "taylor_local" else case.history_outputs)
    methods = {
        "taylor_local": ({"kind": "taylor-local"}, {"workers": 0}),
        "taylor": ({"kind": "taylor", "order": 2, "variance": "first-order",
                    "step_check": False, "step": case.step}, {"workers": 0}),
    }
    method_table, execution = methods.get(method, (
        {"kind": "monte-carlo", "samples": MC_SAMPLES, "rule": "sobol",
         "replicates": MC_REPLICATES, "control": "taylor", "control_step": case.step},
        {"workers": 2, "seed": MC_SEED}))
    return write_normal_study(folder / f"{case.key}_{method}.toml", name=f"{case.key}-{method}",
                              scene=f"scene_{case.example}.toml", outputs=outputs,
                              means=case.inputs, cv=case.cv, method=method_table,
                              execution=execution, result=f"{case.key}_{method}.nc")

def run_all(folder: Path, reuse: bool) -> None:
    """Run every study (with ``reuse``, only those without a result file yet)."""
    import uqflow
    folder.mkdir(parents=True, exist_ok=True)
    for example in ("thin", "thick"):
        write_scene(example, folder)
    for case in CASES:
        for method in METHODS:
            study_file = write_study(case, method, folder)
            result = folder / f"{case.key}_{method}.nc"
            if reuse and result.exists():
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                uqflow.run_study(uqflow.load_study(study_file), force=True,
                                 show_progress=False)
            print(f"{case.key} {method}: done", flush=True)



# ------------------------------------------------------------------------------ analysis

@dataclass
class Results:
    case: Case
    local: xr.Dataset         # taylor-local statistics
    whole: xr.Dataset         # taylor statistics
    whole_runs: xr.Dataset    # taylor's stencil runs
    ref: xr.Dataset           # reference statistics


def load(folder: Path, case: Case) -> Results:
    import uqflow
    trees = {m: uqflow.open_result(folder / f"{case.key}_{m}.nc") for m in METHODS}
    return Results(case, trees["taylor_local"]["statistics"].to_dataset(),
                   trees["taylor"]["statistics"].to_dataset(),
                   trees["taylor"]["runs"].to_dataset(),
                   trees["reference"]["statistics"].to_dataset())


def stat(ds: xr.Dataset, out: str, label: str) -> np.ndarray:
    return np.asarray(ds[out].sel(statistic=label).values, float)


@dataclass
class Agreement:
    """One method (or method pair) against the reference's error over every (time, probe)."""
    beyond_mean: float        # share of the points with |delta mean| > T7 stderr
    beyond_var: float         # share of the active points with |delta var| > T7 var stderr
    median_mean: float        # median |delta mean| / reference std over the active points
    worst_mean: tuple[float, str, float]   # (value, probe, time in us)
    median_var: float         # median |var / var_ref - 1| over the active points
    worst_var: tuple[float, str, float]
    beyond_mean_late: float   # share beyond in mean after LATE_US
    beyond_var_late: float


#: The shock has crossed every probe by then (peak pressures at 8.5-13 us, docs/mpm_scenes.md).
LATE_US = 20.0
#: A point is "active" where the reference std exceeds this share of its probe's largest std
#: over time: before the shock arrives S11, S22 are exactly 0 in every run and a relative
#: error of a variance has no meaning.
ACTIVE_SHARE = 0.01


def active_points(ref_std: np.ndarray) -> np.ndarray:
    return ref_std > ACTIVE_SHARE * ref_std.max(axis=0, keepdims=True)


def agreement(mean, var, ref: xr.Dataset, out: str, other=None) -> Agreement:
    """``mean``, ``var`` (time, probe) against the reference's, or against ``other``'s
    (mean, var) judged with the reference's standard errors."""
    r_mean, r_var = stat(ref, out, "mean"), stat(ref, out, "variance")
    se_mean = stat(ref, out, "stderr")
    se_var = np.asarray(ref[f"{out}_variance_stderr"].values, float)
    if other is not None:
        r_mean, r_var = other
    r_std = np.sqrt(stat(ref, out, "variance"))
    active = active_points(r_std)
    # A difference at the rounding level of the output is no disagreement even where the
    # reference's error is 0 (S11 before the shock: 0 in every run).
    rounding = 1e-12 * np.nanmax(np.abs(r_mean))
    d_mean, d_var = np.abs(mean - r_mean), np.abs(var - r_var)
    beyond_m = d_mean > T7 * se_mean + rounding
    beyond_v = (d_var > T7 * se_var + rounding ** 2) & active
    times = np.asarray(ref["time"].values) * 1e6
    probes = [str(p) for p in ref["probe"].values]
    late = times > LATE_US
    rel_mean = np.where(active, d_mean / np.where(active, r_std, 1.0), np.nan)
    rel_var = np.where(active, np.abs(var / np.where(active, r_var, 1.0) - 1.0), np.nan)

    def worst(a):
        k, j = np.unravel_index(np.nanargmax(a), a.shape)
        return float(a[k, j]), probes[j], float(times[k])

    return Agreement(float(beyond_m.mean()), float(beyond_v.sum() / max(active.sum(), 1)),
                     float(np.nanmedian(rel_mean)), worst(rel_mean),
                     float(np.nanmedian(rel_var)), worst(rel_var),
                     float(beyond_m[late].mean()),
                     float(beyond_v[late].sum() / max(active[late].sum(), 1)))


def agreements(res: Results) -> list[tuple[str, str, Agreement]]:
    rows = []
    for out in res.case.local_outputs:
        tl = stat(res.local, out, "mean"), stat(res.local, out, "variance")
        wh = stat(res.whole, out, "mean"), stat(res.whole, out, "variance")
        rows.append((out, "taylor-local vs reference", agreement(*tl, res.ref, out)))
        rows.append((out, "taylor vs reference", agreement(*wh, res.ref, out)))
        rows.append((out, "taylor-local vs taylor", agreement(*tl, res.ref, out, other=wh)))
    for out in res.case.history_outputs:
        wh = stat(res.whole, out, "mean"), stat(res.whole, out, "variance")
        rows.append((out, "taylor vs reference", agreement(*wh, res.ref, out)))
    return rows


def agreement_table(all_results: list[Results]) -> str:
    head = ("| case | output | comparison | beyond T7 σ̂, mean | beyond, var | after "
            f"{LATE_US:g} µs: mean / var | median |Δmean|/σ_ref | worst (probe, µs) | "
            "median |var/var_ref − 1| | worst (probe, µs) |\n|" + "---|" * 10)
    lines = [head]
    for res in all_results:
        for out, what, a in agreements(res):
            lines.append(
                f"| {res.case.example} {res.case.cv:.2f} | {out} | {what} | "
                f"{100 * a.beyond_mean:.1f} % | {100 * a.beyond_var:.1f} % | "
                f"{100 * a.beyond_mean_late:.1f} / {100 * a.beyond_var_late:.1f} % | "
                f"{a.median_mean:.3f} | {a.worst_mean[0]:.2f} ({a.worst_mean[1]}, "
                f"{a.worst_mean[2]:g}) | {a.median_var:.3f} | {a.worst_var[0]:.2f} "
                f"({a.worst_var[1]}, {a.worst_var[2]:g}) |")
    return "\n".join(lines)



# ------------------------------------------------------------------------------ physics

def _at(times_us: np.ndarray, t: float) -> int:
    return int(np.argmin(np.abs(times_us - t)))


def gradient(ds: xr.Dataset, out: str, parameter: str) -> np.ndarray:
    return np.asarray(ds[f"{out}_gradient"].sel(parameter=parameter).values, float)


def hardening_slope(res: Results, out: str) -> np.ndarray:
    """d sigma_y / d eps_p at the nominal state: sigma_y n B eps^(n-1) / (A + B eps^n), the
    Johnson-Cook rate and thermal factors held as they are (eps_p = 0: NaN, no slope)."""
    eps = stat(res.whole, "plastic_strain", "nominal")
    sigma = stat(res.whole, out, "nominal")
    a, b, n = JC["A"], JC["B"], JC["n"]
    safe = np.where(eps > 0, eps, 1.0)
    return np.where(eps > 0, sigma * n * b * safe ** (n - 1) / (a + b * safe ** n), np.nan)


def feedback_table(res: Results, out: str = "flow_stress", probe: str = "H",
                   times=(10.0, 20.0, 30.0, 50.0, 75.0, 100.0)) -> str:
    """The A-derivative of sigma_y both ways, and the feedback eps_p carries between them."""
    times_us = np.asarray(res.ref["time"].values) * 1e6
    j = [str(p) for p in res.ref["probe"].values].index(probe)
    local = gradient(res.local, out, "steel.jc.A")[:, j]
    whole = gradient(res.whole, out, "steel.jc.A")[:, j]
    deps = gradient(res.whole, "plastic_strain", "steel.jc.A")[:, j]
    eps = stat(res.whole, "plastic_strain", "nominal")[:, j]
    slope = hardening_slope(res, out)[:, j]
    lines = ["| t (µs) | εp (nominal) | ∂σy/∂A frozen (`taylor-local`) | ∂σy/∂A whole solver "
             "(`taylor`) | ∂εp/∂A (1/GPa, `taylor`) | ∂σy/∂εp (GPa) | frozen + ∂σy/∂εp · "
             "∂εp/∂A |", "|" + "---|" * 7]
    for t in times:
        k = _at(times_us, t)
        lines.append(f"| {times_us[k]:g} | {eps[k]:.3f} | {local[k]:.3f} | {whole[k]:.3f} | "
                     f"{deps[k] * 1e9:.4f} | {slope[k] / 1e9:.2f} | "
                     f"{local[k] + slope[k] * deps[k]:.3f} |")
    return "\n".join(lines)


def std_ratio_table(all_results: list[Results]) -> str:
    """Median over the active points after LATE_US of std / reference std, per probe."""
    lines = [f"| case | output | `taylor-local` std / reference std, median after {LATE_US:g} "
             "µs, per probe | `taylor` std / reference std |", "|---|---|---|---|"]
    for res in all_results:
        times_us = np.asarray(res.ref["time"].values) * 1e6
        probes = [str(p) for p in res.ref["probe"].values]
        for out in res.case.local_outputs:
            ref_std = np.sqrt(stat(res.ref, out, "variance"))
            keep = active_points(ref_std) & (times_us > LATE_US)[:, None]
            cells = []
            for ds in (res.local, res.whole):
                ratio = np.sqrt(stat(ds, out, "variance")) / np.where(keep, ref_std, 1.0)
                cells.append(", ".join(f"{p} {np.median(ratio[keep[:, j], j]):.2f}"
                                       for j, p in enumerate(probes)))
            lines.append(f"| {res.case.example} {res.case.cv:.2f} | {out} | {cells[0]} | "
                         f"{cells[1]} |")
    return "\n".join(lines)


def elastic_table(all_results: list[Results]) -> str:
    """Deviator points where every local derivative is 0 (elastic steps of the nominal run)."""
    lines = ["| case | output | active points with all local derivatives 0 | reference std "
             "there (median, GPa) | elsewhere | of the variance points beyond T7: at zero "
             "derivatives | `taylor-local` mean with order 1 (f(μ)) beyond T7 / with order 2 |",
             "|" + "---|" * 7]
    for res in all_results:
        for out in ("S11", "S22"):
            if out not in res.case.local_outputs:
                continue
            grad = np.asarray(res.local[f"{out}_gradient"].values, float)
            zero = np.all(grad == 0.0, axis=0)
            ref_std = np.sqrt(stat(res.ref, out, "variance"))
            active = active_points(ref_std)
            se_var = np.asarray(res.ref[f"{out}_variance_stderr"].values, float)
            beyond = active & (np.abs(stat(res.local, out, "variance")
                                      - stat(res.ref, out, "variance")) > T7 * se_var)
            first = agreement(stat(res.local, out, "nominal"), stat(res.local, out, "variance"),
                              res.ref, out).beyond_mean
            second = agreement(stat(res.local, out, "mean"), stat(res.local, out, "variance"),
                               res.ref, out).beyond_mean
            lines.append(
                f"| {res.case.example} {res.case.cv:.2f} | {out} | "
                f"{100 * (zero & active).sum() / active.sum():.1f} % | "
                f"{np.median(ref_std[zero & active]) / 1e9:.3f} | "
                f"{np.median(ref_std[~zero & active]) / 1e9:.3f} | "
                f"{100 * (zero & beyond).sum() / max(beyond.sum(), 1):.1f} % | "
                f"{100 * first:.1f} % / {100 * second:.1f} % |")
    return "\n".join(lines)


def plastic_step_table(all_results: list[Results]) -> str:
    """The deviator in plastic steps after LATE_US (some local derivative non-zero): the
    first-order std from the frozen derivatives over the one from the whole-solver ones, and
    how the two A-derivatives follow each other over time."""
    lines = [f"| case | output | plastic-step points after {LATE_US:g} µs, per probe | "
             "frozen / whole-solver first-order std (median) | ∂/∂A frozen / whole (median) | "
             "correlation over time of the two ∂/∂A |", "|---|---|---|---|---|---|"]
    for res in all_results:
        times_us = np.asarray(res.ref["time"].values) * 1e6
        probes = [str(p) for p in res.ref["probe"].values]
        sigma = np.asarray(res.whole["input_std"].values, float)[:, None, None]
        for out in ("S11", "S22"):
            if out not in res.case.local_outputs:
                continue
            local = np.asarray(res.local[f"{out}_gradient"].values, float)
            whole = np.asarray(res.whole[f"{out}_gradient"].values, float)
            with np.errstate(invalid="ignore", divide="ignore"):   # 0/0 before the shock
                ratio = np.sqrt(((local * sigma) ** 2).sum(0) / ((whole * sigma) ** 2).sum(0))
            plastic = ~np.all(local == 0.0, axis=0) & (times_us > LATE_US)[:, None]
            a = [str(q) for q in res.local["parameter"].values].index("steel.jc.A")
            cells = [[], [], [], []]
            for j, probe in enumerate(probes):
                m = plastic[:, j]
                cells[0].append(f"{probe} {m.sum()}")
                cells[1].append(f"{probe} {np.median(ratio[m, j]):.2f}")
                cells[2].append(f"{probe} {np.median(local[a, m, j] / whole[a, m, j]):.2f}")
                cells[3].append(f"{probe} {np.corrcoef(local[a, m, j], whole[a, m, j])[0, 1]:.2f}")
            lines.append(f"| {res.case.example} {res.case.cv:.2f} | {out} | "
                         + " | ".join(", ".join(c) for c in cells) + " |")
    return "\n".join(lines)


def crossing_time(series: np.ndarray, times_us: np.ndarray, level: float,
                  falling: bool = False) -> float:
    """First time (µs) the series rises to ``level`` (or, with ``falling``, first falls back
    below it after its peak), linearly interpolated between output times."""
    start = int(np.argmax(series)) if falling else 0
    s = -series[start:] if falling else series
    k = int(np.argmax(s >= (-level if falling else level)))
    if k == 0:
        return math.nan
    k += start
    return float(times_us[k - 1] + (level - series[k - 1]) / (series[k] - series[k - 1])
                 * (times_us[k] - times_us[k - 1]))


def stencil_rows(runs: xr.Dataset, parameter: str) -> tuple[int, int, int, float]:
    """Rows of the nominal run and of mu + h, mu - h for ``parameter``, and h."""
    x = np.asarray(runs["inputs"].values, float)
    k = [str(p) for p in runs["parameter"].values].index(parameter)
    mu = np.asarray(runs["input_mean"].values, float)
    others = np.all(np.delete(x, k, axis=1) == np.delete(mu, k), axis=1)
    nominal = int(np.flatnonzero(others & (x[:, k] == mu[k]))[0])
    up = int(np.flatnonzero(others & (x[:, k] > mu[k]))[0])
    down = int(np.flatnonzero(others & (x[:, k] < mu[k]))[0])
    return nominal, up, down, float(x[up, k] - mu[k])


def pulse_timing(res: Results, probe: int) -> dict:
    """How S1 moves the compressive pulse at a probe, from `taylor`'s three S1 stencil runs:
    the times the pressure rises through and falls back below half the nominal peak, their
    S1-derivatives, and the S1-derivative of p that a pure time shift of the nominal series
    would give, -(dp/dt) dt/dS1, at the time |dp/dS1| (`taylor`) peaks near each crossing."""
    runs = res.whole_runs
    times_us = np.asarray(runs["time"].values) * 1e6
    nominal, up, down, h = stencil_rows(runs, "steel.eos.S1")
    p = np.asarray(runs["pressure"].values, float)[:, :, probe]
    level = 0.5 * p[nominal].max()
    dpdt = np.gradient(p[nominal], times_us)          # Pa / µs
    whole = gradient(res.whole, "pressure", "steel.eos.S1")[:, probe]
    local = gradient(res.local, "pressure", "steel.eos.S1")[:, probe]
    timing = {}
    for edge, falling in (("rise", False), ("fall", True)):
        t0 = crossing_time(p[nominal], times_us, level, falling)
        slope = (crossing_time(p[up], times_us, level, falling)
                 - crossing_time(p[down], times_us, level, falling)) / (2 * h)
        near = np.flatnonzero(np.abs(times_us - t0) <= 2.0)
        k = int(near[np.argmax(np.abs(whole[near]))])
        timing[edge] = dict(t=t0, dt_dS1=slope, t_max=float(times_us[k]), whole=whole[k],
                            local=local[k], shift=-dpdt[k] * slope)
    return timing


def timing_table(all_results: list[Results]) -> str:
    lines = ["| case | probe | edge | at (µs) | ∂t/∂S1 (ns) | shift at 1 σ (ns) | at t (µs) "
             "where |∂p/∂S1| (`taylor`) peaks within 2 µs: whole solver / frozen state / "
             "pure shift −(dp/dt)·∂t/∂S1 (GPa) |", "|" + "---|" * 7]
    for res in all_results:
        if res.case.example != "thick":
            continue
        sigma = float(res.whole["input_std"].sel(parameter="steel.eos.S1"))
        for j, probe in enumerate(str(q) for q in res.whole_runs["probe"].values):
            for edge, d in pulse_timing(res, j).items():
                lines.append(f"| thick {res.case.cv:.2f} | {probe} | {edge} | {d['t']:.2f} | "
                             f"{d['dt_dS1'] * 1e3:.0f} | {d['dt_dS1'] * sigma * 1e3:.1f} | "
                             f"{d['t_max']:g}: {d['whole'] / 1e9:.2f} / "
                             f"{d['local'] / 1e9:.2f} / {d['shift'] / 1e9:.2f} |")
    return "\n".join(lines)



# ------------------------------------------------------------------------------ figures

COLOURS = {"taylor-local": "tab:red", "taylor": "tab:blue", "reference": "black"}


def _moment_panels(axes, res: Results, out: str, probe: str, scale: float, unit: str):
    times_us = np.asarray(res.ref["time"].values) * 1e6
    j = [str(p) for p in res.ref["probe"].values].index(probe)
    mean, var = stat(res.ref, out, "mean")[:, j], stat(res.ref, out, "variance")[:, j]
    se_mean = stat(res.ref, out, "stderr")[:, j]
    se_var = np.asarray(res.ref[f"{out}_variance_stderr"].values, float)[:, j]
    band = f"reference ± {T7:.2f} s.e. (t₇ 99.73 %)"
    axes[0].fill_between(times_us, (mean - T7 * se_mean) / scale, (mean + T7 * se_mean) / scale,
                         color="0.75", label=band)
    axes[1].fill_between(times_us, np.sqrt(np.maximum(var - T7 * se_var, 0)) / scale,
                         np.sqrt(var + T7 * se_var) / scale, color="0.75", label=band)
    axes[0].plot(times_us, mean / scale, color="black", lw=0.8, label="reference (MC, CV)")
    axes[1].plot(times_us, np.sqrt(var) / scale, color="black", lw=0.8,
                 label="reference (MC, CV)")
    for label, ds in (("taylor-local", res.local), ("taylor", res.whole)):
        axes[0].plot(times_us, stat(ds, out, "mean")[:, j] / scale, color=COLOURS[label],
                     lw=0.9, ls="--" if label == "taylor" else "-", label=label)
        axes[1].plot(times_us, np.sqrt(stat(ds, out, "variance")[:, j]) / scale,
                     color=COLOURS[label], lw=0.9, ls="--" if label == "taylor" else "-",
                     label=label)
    axes[0].set_ylabel(f"mean {out} at {probe} ({unit})")
    axes[1].set_ylabel(f"std ({unit})")
    for ax in axes:
        ax.set_xlabel("t (µs)")


def draw_moments(res: Results, rows: list[tuple[str, str]], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(rows), 2, figsize=(9, 2.9 * len(rows)), squeeze=False)
    for row, (out, probe) in zip(axes, rows):
        _moment_panels(row, res, out, probe, 1e9, "GPa")
    axes[0, 1].legend(fontsize=7)
    fig.suptitle(f"{res.case.example} plate, C.V. {res.case.cv:.2f}, resolution {RESOLUTION}",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)


def draw_gradients(thin: Results, thick: Results, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.6))
    times_us = np.asarray(thin.ref["time"].values) * 1e6
    j = [str(p) for p in thin.ref["probe"].values].index("H")
    local = gradient(thin.local, "flow_stress", "steel.jc.A")[:, j]
    feedback = hardening_slope(thin, "flow_stress")[:, j] \
        * gradient(thin.whole, "plastic_strain", "steel.jc.A")[:, j]
    left.plot(times_us, local, color=COLOURS["taylor-local"], lw=0.9, label="frozen state")
    left.plot(times_us, gradient(thin.whole, "flow_stress", "steel.jc.A")[:, j],
              color=COLOURS["taylor"], lw=0.9, label="whole solver")
    left.plot(times_us, local + feedback, color="tab:green", lw=0.9, ls=":",
              label="frozen + ∂σy/∂εp · ∂εp/∂A")
    left.set(xlabel="t (µs)", ylabel="∂σy/∂A at H", ylim=(0.6, 1.3),
             title=f"thin plate, C.V. {thin.case.cv:.2f}")
    left.legend(fontsize=7)
    times_us = np.asarray(thick.ref["time"].values) * 1e6
    runs = thick.whole_runs
    nominal, _, _, _ = stencil_rows(runs, "steel.eos.S1")
    p = np.asarray(runs["pressure"].values, float)[nominal, :, 0]
    fall = pulse_timing(thick, 0)["fall"]["dt_dS1"]
    right.plot(times_us, gradient(thick.local, "pressure", "steel.eos.S1")[:, 0] / 1e9,
               color=COLOURS["taylor-local"], lw=0.9, label="frozen state")
    right.plot(times_us, gradient(thick.whole, "pressure", "steel.eos.S1")[:, 0] / 1e9,
               color=COLOURS["taylor"], lw=0.9, label="whole solver")
    right.plot(times_us, -np.gradient(p, times_us) * fall / 1e9, color="tab:green", lw=0.9,
               ls=":", label="pure time shift −(dp/dt)·∂t_fall/∂S1")
    right.set(xlabel="t (µs)", ylabel="∂p/∂S1 at E (GPa)", xlim=(0, 50),
              title=f"thick plate, C.V. {thick.case.cv:.2f}")
    right.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)


def peak_table(all_results: list[Results]) -> str:
    """The pressure pulse's std by method: at the reference mean's peak, where a time shift
    moves p least (dp/dt = 0), and the largest std within the pulse (10 µs either side)."""
    lines = ["| case | probe | peak mean p (GPa) at t (µs) | std there: `taylor-local` / "
             "`taylor` / reference (GPa) | largest std within ±10 µs, at t (µs): "
             "`taylor-local` / `taylor` / reference |", "|---|---|---|---|---|"]
    for res in all_results:
        if res.case.example != "thick":
            continue
        times_us = np.asarray(res.ref["time"].values) * 1e6
        stds = [np.sqrt(stat(ds, "pressure", "variance"))
                for ds in (res.local, res.whole, res.ref)]
        mean = stat(res.ref, "pressure", "mean")
        for j, probe in enumerate(str(q) for q in res.ref["probe"].values):
            k = int(np.argmax(mean[:, j]))
            near = np.abs(times_us - times_us[k]) <= 10.0
            at = " / ".join(f"{np.max(s[near, j]) / 1e9:.3f} "
                           f"({times_us[near][np.argmax(s[near, j])]:g})" for s in stds)
            lines.append(f"| thick {res.case.cv:.2f} | {probe} | {mean[k, j] / 1e9:.2f} at "
                         f"{times_us[k]:g} | "
                         + " / ".join(f"{s[k, j] / 1e9:.3f}" for s in stds)
                         + f" | {at} |")
    return "\n".join(lines)


def cost_table(all_results: list[Results]) -> str:
    lines = ["| case | `taylor-local` runs | `taylor` runs | reference runs (control + samples) "
             "| reference: failed |", "|---|---|---|---|---|"]
    for res in all_results:
        lines.append(f"| {res.case.example} {res.case.cv:.2f} | "
                     f"{res.local.attrs['solver_runs']} | {res.whole.attrs['solver_runs']} | "
                     f"{res.ref.attrs['solver_runs']} | {res.ref.attrs['failed_runs']} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scratch", type=Path, default=Path("/tmp/smpm_local_vs_global"))
    parser.add_argument("--reuse", action="store_true",
                        help="analyse existing result files instead of rerunning them")
    args = parser.parse_args()
    run_all(args.scratch, args.reuse)
    results = [load(args.scratch, case) for case in CASES]
    by_key = {res.case.key: res for res in results}
    FIGURES.mkdir(parents=True, exist_ok=True)
    figures = {"thin": FIGURES / "smpm_local_vs_global_thin.png",
               "thick": FIGURES / "smpm_local_vs_global_thick.png",
               "gradients": FIGURES / "smpm_local_vs_global_gradients.png"}
    draw_moments(by_key["thin_cv0.15"], [("flow_stress", "H"), ("S11", "H"), ("S22", "I")],
                 figures["thin"])
    draw_moments(by_key["thick_cv0.15"], [("pressure", "E"), ("pressure", "F")],
                 figures["thick"])
    draw_gradients(by_key["thin_cv0.10"], by_key["thick_cv0.01"], figures["gradients"])
    total_runs = sum(int(ds.attrs["solver_runs"]) for res in results
                     for ds in (res.local, res.whole, res.ref))
    body = f"""
With `--reuse` the command re-analyses the result files that a run of it without `--reuse`
wrote into its scratch folder ({total_runs} solver runs in all).

Scenes: the small contact-explosion scenes at **resolution {RESOLUTION}** (10 mm cells, 8,400
particles, nearest-particle probes). Per case `taylor-local` (1 run), `taylor` (2n+1 runs,
first-order variance; thin step = 1 std, thick 0.1 std) and the reference: Monte Carlo with
`control = "taylor"` (same step) on {MC_SAMPLES} = {MC_REPLICATES} × {MC_SAMPLES // MC_REPLICATES}
scrambled Sobol' points, seed {MC_SEED} (the same normal draws at every C.V.), 2 dask workers;
its standard errors of mean and variance come from its {MC_REPLICATES} replicates
({MC_REPLICATES - 1} degrees of freedom). A point disagrees where |Δ| > {T7:.2f} reference
standard errors (two-sided 99.73 % of t₇, docs/mpm_scenes.md). Points: 201 output times ×
probes; variance statistics only over the "active" points, where the reference std exceeds
{100 * ACTIVE_SHARE:g} % of its probe's largest (S11, S22 are 0 in every run before the shock).
Relative errors: |Δmean| in reference stds, |var/var_ref − 1|.

{cost_table(results)}

**Agreement over the whole time series**

{agreement_table(results)}

**Std against the reference after {LATE_US:g} µs** (median over the active points)

{std_ratio_table(results)}

**Feedback of A on the plastic strain** (thin, C.V. 0.10, probe H; `flow_stress`)

{feedback_table(by_key["thin_cv0.10"])}

**Deviator in elastic steps** (all local derivatives of the probe's S11, S22 exactly 0)

{elastic_table(results)}

**Deviator in plastic steps** (the frozen derivative is radial: (3G/(3G+H)) (S/σeq) ∂σy/∂θ)

{plastic_step_table(results)}

**Pulse timing and S1** (thick; `taylor`'s S1 stencil runs, half the nominal peak)

{timing_table(results)}

**The pulse's std** (thick)

{peak_table(results)}

Figures: `docs/figures/smpm_local_vs_global_thin.png` (thin, C.V. 0.15: σy at H, S11 at H,
S22 at I; mean and std, reference band), `docs/figures/smpm_local_vs_global_thick.png`
(thick, C.V. 0.15: p at E, F), `docs/figures/smpm_local_vs_global_gradients.png` (∂σy/∂A at
H, thin C.V. 0.10; ∂p/∂S1 at E, thick C.V. 0.01).
"""
    write_section("smpm-local-vs-global", "MPM: one run (taylor-local) or 2n+1 (taylor) "
                  "against Monte Carlo over whole time series", body)
    print(body)


if __name__ == "__main__":
    main()
