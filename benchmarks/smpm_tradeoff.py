"""Which method for an MPM study: the speed-accuracy trade, measured on seed example 2.

Thin plate (studies/scenes/mpm_contact_thin_small.toml), Johnson-Cook A, B, C, n, m normal
and independent; outputs flow_stress, S11, S22 at H, I, G, K. Benchmark size (stated up
front, the `Config` below):

* main comparison at resolution 0.5 (10 mm cells, 8,400 particles), C.V. 0.10. Reference:
  Monte Carlo with `control = "taylor-local"` on 256 = 8 x 32 scrambled Sobol' points
  (seed 1) plus its one control run, on 2 dask workers, with its standard errors.
  `taylor-local` (1 run), `taylor` (11 runs, step 1 std as the shipped study), plain
  `monte-carlo` random (64 own runs, seed 2; nested prefixes, which are i.i.d. samples too),
  lhs (own runs at 16 and 64, seeds 3, 4), sobol (nested whole-replicate prefixes of the
  reference's 256 samples), control-variate MC (prefixes of the reference: the control run
  plus the first 8 x 2^k samples) and `pce` orders 1-3 (and the LOO-chosen order) on nested
  prefixes of the reference's samples (their germ is (x - mu)/sigma of those very points).
* sweep over C.V. 0.01, 0.03, 0.10, 0.20, 0.30 at resolution 0.25 (20 mm cells, 2,100
  particles: 6x cheaper): the same standard-normal draws at every C.V. (one seed, x = mu(1 +
  cv z)); per C.V. a reference (control-variate MC, 8 x 16 Sobol' + 1), `taylor-local`,
  `taylor`, `pce` (order by LOO up to 3, 64 own Sobol' runs, seed 2) and control-variate MC
  on the reference's first 8 x 2 samples.

Quantities: each output at the seed-matched time (9 us, docs/mpm_scenes.md), at 100 us, and
its peak over time (max |y| of each realization's series; `taylor-local` and the
control-variate surrogate take the derivatives at the nominal run's argmax time, sign
included: Danskin's theorem, exact to first order where the argmax is unique).

    python benchmarks/smpm_tradeoff.py [--scratch DIR] [--reuse]

Result files go to the scratch folder (default /tmp/smpm_tradeoff); ``--reuse`` re-analyses
existing ones. Writes docs/figures/smpm_tradeoff_*.png and the section "smpm-tradeoff" of
BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import statistics as pystats
import sys
import time
import warnings as pywarnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.stats as sps
import xarray as xr

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import FIGURES, write_section  # noqa: E402
from _studies import write_normal_study, write_scene_variant  # noqa: E402

from solvers.mpm import reductions  # noqa: E402
from solvers.mpm.materials import johnson_cook  # noqa: E402

# the study means: the 4340 defaults of the flow-stress parameters (seed Table 5)
JC = {name.removeprefix("jc."): johnson_cook.PARAMETERS[name]
      for name in johnson_cook.DIFFERENTIABLE_PARAMETERS}
OUTPUTS = ["flow_stress", "S11", "S22"]
#: The seed's 10,000-sample Monte Carlo (its Tables 3 and 9), against which speed-ups count.
SEED_MC_RUNS = 10_000


@dataclass(frozen=True)
class Config:
    resolution: float = 0.5
    sweep_resolution: float = 0.25
    end_time: float | None = None          # None: the scene's 100 us
    cv: float = 0.10
    sweep_cvs: tuple = (0.01, 0.03, 0.10, 0.20, 0.30)
    replicates: int = 8
    ref_samples: int = 256
    sweep_ref_samples: int = 128
    sweep_cv_samples: int = 16              # control-variate MC in the sweep (a prefix)
    random_samples: int = 64
    lhs_sizes: tuple = (16, 64)
    sweep_pce_samples: int = 64
    pce_check_runs: int = 64                # check (b): at most 100 runs
    taylor_step: float = 1.0
    seed_time_us: float = 9.0
    timing_repeats: int = 5
    workers: int = 2
    failure_resolution: float = 0.125
    failure_samples: int = 16


#: What the tests run: the same machinery at a toy size (seconds).
TOY = Config(resolution=0.125, sweep_resolution=0.125, sweep_cvs=(0.03, 0.3), replicates=2,
             ref_samples=16, sweep_ref_samples=8, sweep_cv_samples=4, random_samples=8,
             lhs_sizes=(8,), sweep_pce_samples=16, pce_check_runs=16, timing_repeats=1,
             workers=0, failure_samples=8)


# ------------------------------------------------------------------------------ studies

def write_scene(folder: Path, resolution: float, end_time: float | None) -> str:
    """The shipped small thin-plate scene at ``resolution`` with OUTPUTS only."""
    name = f"scene_r{resolution:g}.toml"
    keys = {"resolution": resolution, "outputs": list(OUTPUTS)}
    if end_time is not None:
        keys["end_time"] = end_time
    write_scene_variant("mpm_contact_thin_small.toml", folder / name, **keys)
    return name

def write_study(folder: Path, name: str, scene: str, cv: float, method: dict, workers: int,
                seed: int, cv_overrides: dict | None = None) -> Path:
    cvs = {f"steel.jc.{k}": (cv_overrides or {}).get(k, cv) for k in JC}
    return write_normal_study(folder / f"{name}.toml", name=name, scene=scene, outputs=OUTPUTS,
                              means={f"steel.jc.{k}": v for k, v in JC.items()}, cv=cvs,
                              method=method, execution={"workers": workers, "seed": seed,
                                                        "max_failure_fraction": 0.5},
                              result=f"{name}.nc")

@dataclass
class Run:
    """A study's design (re-planned from its seed), runs and result attributes."""
    study: object
    design: xr.Dataset
    runs: xr.Dataset
    attrs: dict
    statistics: xr.Dataset


def run(study_file: Path, reuse: bool) -> Run:
    import uqflow
    from uqflow.store import open_result
    study = uqflow.load_study(study_file)
    design = study.method.plan(study.space, None, np.random.SeedSequence(study.spec.execution.seed))
    result = study.output_path
    started = time.perf_counter()
    if not (reuse and result.exists()):
        with pywarnings.catch_warnings():
            pywarnings.simplefilter("ignore")
            uqflow.run_study(study, force=True, show_progress=False)
        print(f"  {study.name}: {design.sizes['realization']} runs, "
              f"{time.perf_counter() - started:.1f} s", flush=True)
    tree = open_result(result)
    runs = tree["runs"].to_dataset()
    runs["status"] = runs["status"].astype(object)
    return Run(study, design, runs, dict(tree.attrs), tree["statistics"].to_dataset())


def method_for(kind: str, **options):
    from uqflow.methods.base import get_method
    return get_method(kind)(**options)


# ------------------------------------------------------------------------------ quantities

def at_time(runs: xr.Dataset, time_us: float) -> xr.Dataset:
    """Every output (and its derivatives) at the output time nearest ``time_us``."""
    return reductions.at_time(runs, time_us * 1e-6)


def peak(runs: xr.Dataset) -> xr.Dataset:
    """Each realization's max |y| over time per probe (``reductions.peak_over_time``)."""
    return reductions.peak_over_time(runs, OUTPUTS)


def quantities(cfg: Config) -> dict[str, callable]:
    return {f"{cfg.seed_time_us:g} µs": lambda r: at_time(r, cfg.seed_time_us),
            "100 µs": lambda r: at_time(r, 100.0), "peak": peak}


# ------------------------------------------------------------------------------ subsets

plain_part = reductions.monte_carlo_part     # the Monte Carlo rows of a control-variate run


def pce_design(samples: xr.Dataset, order) -> xr.Dataset:
    """A Monte Carlo design of normal inputs as a `pce` design: its germ is (x - mu)/sigma of
    the same points (what pce's own plan draws, Φ^-1(u), for a normal input)."""
    z = (samples["inputs"].values - samples["input_mean"].values) / samples["input_std"].values
    d = samples.assign(
        standard_normal=(("realization", "parameter"), z),
        standard_uniform=(("realization", "parameter"), sps.norm.cdf(z)),
        basis_family=("parameter", np.array(["hermite"] * samples.sizes["parameter"],
                                            dtype=object)))
    d.attrs = dict(rule=samples.attrs.get("rule", "sobol"), order=str(order),
                   max_order=3 if order == "loo" else order, regression="auto",
                   basis="hermite", input_kinds=",".join(["normal"] * samples.sizes["parameter"]))
    return d


@dataclass
class Estimate:
    method: str
    runs: int
    wall: float               # summed wall time of the solver runs used (s)
    stats: dict               # quantity -> statistics dataset
    warnings: list = field(default_factory=list)


def analyze(method, design, runs, label: str, cfg: Config) -> Estimate:
    stats, fired = {}, []
    for name, reduce in quantities(cfg).items():
        with pywarnings.catch_warnings():
            pywarnings.simplefilter("ignore")
            stats[name] = method.analyze(design, reduce(runs))
        fired += [f"{name}: {w}" for w in stats[name].attrs.get("warnings", "").split("\n") if w]
    ok = runs["status"].values != "pending"
    return Estimate(label, int(ok.sum()), float(np.nansum(runs["wall_time"].values)), stats,
                    fired)


def sizes_up_to(cfg: Config, total: int) -> list[int]:
    n, out = cfg.replicates, []
    while n <= total:
        out.append(n)
        n *= 2
    return out


# ------------------------------------------------------------------------------ errors

def moment(stats: xr.Dataset, out: str, label: str, probe: str) -> np.float64:
    """A numpy scalar: a zero standard error (no spread yet) divides to inf, not an error."""
    return np.float64(stats[out].sel(statistic=label, probe=probe).values)


def errors(est_stats: xr.Dataset, ref: xr.Dataset, out: str, probe: str) -> tuple[float, float]:
    """Relative error of the mean and of the variance against the reference."""
    m, v = moment(est_stats, out, "mean", probe), moment(est_stats, out, "variance", probe)
    mr, vr = moment(ref, out, "mean", probe), moment(ref, out, "variance", probe)
    with np.errstate(divide="ignore", invalid="ignore"):
        return abs(m / mr - 1.0), abs(v / vr - 1.0) if vr > 0 else float("nan")


def ref_rel_stderr(ref: xr.Dataset, out: str, probe: str) -> tuple[float, float]:
    mr, vr = moment(ref, out, "mean", probe), moment(ref, out, "variance", probe)
    se_v = np.float64(ref[f"{out}_variance_stderr"].sel(probe=probe).values)
    return moment(ref, out, "stderr", probe) / abs(mr), se_v / vr if vr > 0 else float("nan")


# ------------------------------------------------------------------------------ main study

@dataclass
class Main:
    ref: Estimate
    curves: dict              # method label -> list[Estimate] (increasing runs)
    per_run: float            # median wall time of one plain run in a worker (s)
    rho2: dict                # quantity -> rho^2 of flow_stress at H
    ref_runs: Run


def main_comparison(folder: Path, cfg: Config, reuse: bool) -> Main:
    scene = write_scene(folder, cfg.resolution, cfg.end_time)
    mc = {"kind": "monte-carlo"}
    ref_run = run(write_study(folder, "ref", scene, cfg.cv, {
        **mc, "samples": cfg.ref_samples, "rule": "sobol", "replicates": cfg.replicates,
        "control": "taylor-local"}, cfg.workers, 1), reuse)
    local_run = run(write_study(folder, "taylor_local", scene, cfg.cv,
                                {"kind": "taylor-local"}, 0, 1), reuse)
    taylor_run = run(write_study(folder, "taylor", scene, cfg.cv, {
        "kind": "taylor", "order": 2, "variance": "first-order", "step_check": False,
        "step": cfg.taylor_step}, 0, 1), reuse)
    random_run = run(write_study(folder, "random", scene, cfg.cv, {
        **mc, "samples": cfg.random_samples, "rule": "random"}, cfg.workers, 2), reuse)
    lhs_runs = [run(write_study(folder, f"lhs{n}", scene, cfg.cv, {
        **mc, "samples": n, "rule": "lhs"}, cfg.workers, 3 + k), reuse)
        for k, n in enumerate(cfg.lhs_sizes)]
    print("main: analysing", flush=True)

    ref = analyze(ref_run.study.method, ref_run.design, ref_run.runs, "reference", cfg)
    curves = {"taylor-local": [analyze(local_run.study.method, local_run.design,
                                       local_run.runs, "taylor-local", cfg)],
              "taylor": [analyze(taylor_run.study.method, taylor_run.design, taylor_run.runs,
                                 "taylor", cfg)]}
    from uqflow.realization import realization_prefix
    curves["MC random"] = []
    for n in sizes_up_to(cfg, cfg.random_samples):
        d, r = (realization_prefix(x, n) for x in (random_run.design, random_run.runs))
        curves["MC random"].append(analyze(method_for("monte-carlo", rule="random", samples=n),
                                           d, r, "MC random", cfg))
    curves["MC lhs"] = [analyze(method_for("monte-carlo", rule="lhs", samples=n), x.design,
                                x.runs, "MC lhs", cfg) for n, x in zip(cfg.lhs_sizes, lhs_runs)]
    sobol, control, pce = [], [], {1: [], 2: [], 3: [], "loo": []}
    for n in sizes_up_to(cfg, cfg.ref_samples):
        d, r = plain_part(ref_run.design, ref_run.runs, n)
        sobol.append(analyze(method_for("monte-carlo", rule="sobol", samples=n,
                                        replicates=cfg.replicates), d, r, "MC sobol", cfg))
        if n < cfg.ref_samples:
            m = 1 + n
            control.append(analyze(
                method_for("monte-carlo", rule="sobol", samples=n, replicates=cfg.replicates,
                           control="taylor-local"),
                realization_prefix(ref_run.design, m), realization_prefix(ref_run.runs, m),
                "MC control variate", cfg))
        for order in pce:
            terms = {1: 6, 2: 21, 3: 56, "loo": 6}[order]     # 5 inputs: C(5 + p, p) terms
            if n < 2 * 6 or (order != "loo" and n < terms // 2):
                continue
            opts = {"order": order, "max_order": 3} if order == "loo" else {"order": order}
            pce[order].append(analyze(method_for("pce", **opts), pce_design(d, order), r,
                                      f"pce {order}", cfg))
    curves["MC sobol"] = sobol
    curves["MC control variate"] = control
    for order, ests in pce.items():
        curves[f"pce order {order}" if order != "loo" else "pce LOO"] = ests
    wall = ref_run.runs["wall_time"].values[ref_run.runs["status"].values == "ok"]
    per_run = float(np.median(np.concatenate(
        [wall[1:], random_run.runs["wall_time"].values])))
    rho2 = {q: float(ref.stats[q]["flow_stress_correlation"].sel(probe="H")) ** 2
            for q in ref.stats}
    return Main(ref, curves, per_run, rho2, ref_run)


# ------------------------------------------------------------------------------ checks

def check_control_variate(main: Main, cfg: Config) -> list[str]:
    """(a) the plain-MC runs that reach the reference's standard error of the mean of σy at
    H, against the reference's own runs."""
    lines = []
    np.seterr(divide="ignore", invalid="ignore")
    for q, ref in main.ref.stats.items():
        se = moment(ref, "flow_stress", "stderr", "H")
        var = moment(ref, "flow_stress", "variance", "H")
        iid = var / se**2
        sob = main.curves["MC sobol"][-1].stats[q]
        se_sobol, n_sobol = moment(sob, "flow_stress", "stderr", "H"), main.curves["MC sobol"][-1].runs
        sobol_needed = n_sobol * (se_sobol / se) ** 2
        ratio = iid / main.ref.runs
        lines.append(
            f"(a) {q}: reference stderr of mean σy at H {se / 1e6:.3g} MPa with {main.ref.runs} "
            f"runs; plain i.i.d. MC needs var/se² = {iid:,.0f} runs ({ratio:,.0f}× more: "
            f"{'≥ 5×, met' if ratio >= 5 else 'short of 5×'}); plain scrambled Sobol' (its own "
            f"stderr {se_sobol / 1e6:.3g} MPa at {n_sobol}, scaled as n^-1/2) ≈ "
            f"{sobol_needed:,.0f} runs ({sobol_needed / main.ref.runs:,.0f}×); ρ² = "
            f"{main.rho2[q]:.4f}, 1/(1−ρ²) = {1 / max(1 - main.rho2[q], 1e-300):.3g}")
    return lines


def check_pce(main: Main, cfg: Config) -> list[str]:
    """(b) pce (order by LOO) on at most 100 runs against the reference's standard errors."""
    lines = []
    chosen = [e for e in main.curves["pce LOO"] if e.runs <= cfg.pce_check_runs]
    if not chosen:
        return ["(b) no pce LOO fit at ≤ 100 runs"]
    est = chosen[-1]
    for q, ref in main.ref.stats.items():
        st = est.stats[q]
        dm = abs(moment(st, "flow_stress", "mean", "H") - moment(ref, "flow_stress", "mean", "H"))
        dv = abs(moment(st, "flow_stress", "variance", "H")
                 - moment(ref, "flow_stress", "variance", "H"))
        zm = dm / moment(ref, "flow_stress", "stderr", "H")
        zv = dv / np.float64(ref["flow_stress_variance_stderr"].sel(probe="H").values)
        loo = float(st["flow_stress_loo_error"].sel(probe="H"))
        order = int(st["flow_stress_order"])
        verdict = "within" if zm <= 1 and zv <= 1 else "NOT within"
        lines.append(f"(b) {q}: pce (LOO order {order}, {est.runs} runs) σy at H {verdict} "
                     f"the reference's standard error: |Δmean| = {zm:.2f} se, |Δvar| = "
                     f"{zv:.2f} se(var); LOO error {loo:.2e}")
    return lines


def time_taylor_local(folder: Path, cfg: Config) -> tuple[float, float, list, list]:
    """(d) one plain run against one run with local sensitivities, alternately, same process
    (medians of ``timing_repeats`` each, after one warm-up of each)."""
    import uqflow
    study = uqflow.load_study(folder / "taylor_local.toml")
    solver = study.solver
    params = solver.nominal()
    wrt = [inp.name for inp in study.space.inputs]
    solver.run(params)
    solver.run_with_sensitivities(params, wrt, OUTPUTS)
    plain, local = [], []
    for _ in range(cfg.timing_repeats):
        t0 = time.perf_counter()
        solver.run(params)
        plain.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        solver.run_with_sensitivities(params, wrt, OUTPUTS)
        local.append(time.perf_counter() - t0)
    return pystats.median(plain), pystats.median(local), plain, local


def failure_study(folder: Path, cfg: Config, reuse: bool) -> list[str]:
    """A realization forced to fail (jc.n with C.V. 1.5: some sampled n <= 0, which the
    solver refuses) in a small control-variate and a small pce study: recorded, the study
    goes on, and how each treated it."""
    scene = write_scene(folder, cfg.failure_resolution, 20e-6)
    lines = []
    for name, method in (
            ("fail_cv", {"kind": "monte-carlo", "samples": cfg.failure_samples, "rule": "sobol",
                         "replicates": 2, "control": "taylor-local"}),
            # pce's linear fit in 5 inputs needs 2 x 6 runs at least
            ("fail_pce", {"kind": "pce", "order": 1, "samples": max(cfg.failure_samples, 16)})):
        got = run(write_study(folder, name, scene, cfg.cv, method, cfg.workers, 5,
                              cv_overrides={"n": 1.5}), reuse)
        status = got.runs["status"].values
        failed = np.flatnonzero(status == "failed")
        msg = str(got.runs["message"].values[failed[0]]) if failed.size else ""
        said = [w for w in got.statistics.attrs.get("warnings", "").split("\n")
                if "fail" in w]
        lines.append(f"{name}: {failed.size} of {status.size} realizations failed "
                     f"(rows {', '.join(map(str, failed))}; first message: {msg[:160]!r}); "
                     f"study complete = {got.attrs.get('complete')}, failed_runs = "
                     f"{got.attrs.get('failed_runs')}; it says: "
                     f"{said[0][:220] if said else '(no failure warning)'}")
    return lines


# ------------------------------------------------------------------------------ sweep

@dataclass
class SweepPoint:
    cv: float
    ref: Estimate
    methods: dict             # label -> Estimate


def sweep(folder: Path, cfg: Config, reuse: bool) -> list[SweepPoint]:
    scene = write_scene(folder, cfg.sweep_resolution, cfg.end_time)
    from uqflow.realization import realization_prefix
    points = []
    for cv in cfg.sweep_cvs:
        tag = f"sweep_cv{cv:g}"
        print(f"sweep C.V. {cv:g}", flush=True)
        ref_run = run(write_study(folder, f"{tag}_ref", scene, cv, {
            "kind": "monte-carlo", "samples": cfg.sweep_ref_samples, "rule": "sobol",
            "replicates": cfg.replicates, "control": "taylor-local"}, cfg.workers, 1), reuse)
        local = run(write_study(folder, f"{tag}_local", scene, cv, {"kind": "taylor-local"},
                                0, 1), reuse)
        taylor = run(write_study(folder, f"{tag}_taylor", scene, cv, {
            "kind": "taylor", "order": 2, "variance": "first-order", "step_check": False,
            "step": cfg.taylor_step}, 0, 1), reuse)
        pce = run(write_study(folder, f"{tag}_pce", scene, cv, {
            "kind": "pce", "order": "loo", "max_order": 3, "samples": cfg.sweep_pce_samples},
            cfg.workers, 2), reuse)
        m = 1 + cfg.sweep_cv_samples
        methods = {
            "taylor-local": analyze(local.study.method, local.design, local.runs,
                                    "taylor-local", cfg),
            "taylor": analyze(taylor.study.method, taylor.design, taylor.runs, "taylor", cfg),
            "pce LOO": analyze(pce.study.method, pce.design, pce.runs, "pce LOO", cfg),
            "MC control variate": analyze(
                method_for("monte-carlo", rule="sobol", samples=cfg.sweep_cv_samples,
                           replicates=cfg.replicates, control="taylor-local"),
                realization_prefix(ref_run.design, m), realization_prefix(ref_run.runs, m),
                "MC control variate", cfg)}
        points.append(SweepPoint(cv, analyze(ref_run.study.method, ref_run.design,
                                             ref_run.runs, "reference", cfg), methods))
    return points


def leaves(points: list[SweepPoint], label: str, q: str, which: int, level: float) -> str:
    """The smallest C.V. at which ``label``'s error (0 mean, 1 variance) of σy at H exceeds
    ``level`` and stays above the reference's own 2 standard errors there."""
    for k, p in enumerate(points):
        err = errors(p.methods[label].stats[q], p.ref.stats[q], "flow_stress", "H")[which]
        noise = 2 * ref_rel_stderr(p.ref.stats[q], "flow_stress", "H")[which]
        if err > max(level, noise):
            return f"{p.cv:g}" if k else f"≤ {p.cv:g} (never within)"
    return f"> {points[-1].cv:g}"


# ------------------------------------------------------------------------------ figures

STYLE = {"taylor-local": ("tab:red", "o"), "taylor": ("tab:blue", "s"),
         "pce order 1": ("tab:olive", "^"), "pce order 2": ("tab:green", "^"),
         "pce order 3": ("darkgreen", "^"), "pce LOO": ("lime", "v"),
         "MC random": ("0.5", "x"), "MC lhs": ("tab:brown", "+"),
         "MC sobol": ("tab:purple", "d"), "MC control variate": ("black", "*")}


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def draw_tradeoff(main: Main, q: str, path: Path) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    se = ref_rel_stderr(main.ref.stats[q], "flow_stress", "H")
    for which, ax in enumerate(axes):
        for label, ests in main.curves.items():
            if not ests:
                continue
            colour, marker = STYLE[label]
            x = [e.runs for e in ests]
            y = [max(errors(e.stats[q], main.ref.stats[q], "flow_stress", "H")[which], 1e-7)
                 for e in ests]
            ax.loglog(x, y, color=colour, marker=marker, ms=4, lw=0.9, label=label)
        ax.axhline(se[which], color="0.6", ls="--", lw=0.8, label="reference's own stderr")
        _label_panel(ax, "solver runs", q, which)
    _finish(plt, fig, axes[1], path)


def _label_panel(ax, xlabel: str, q: str, which: int) -> None:
    ax.set(xlabel=xlabel, ylabel=("|mean/mean_ref − 1|", "|var/var_ref − 1|")[which],
           title=f"σy at H, {q}: {('mean', 'variance')[which]}")


def _finish(plt, fig, legend_axis, path: Path) -> None:
    """One legend for both panels, right of them (it hid the curves inside a panel)."""
    handles, labels = legend_axis.get_legend_handles_labels()
    fig.tight_layout(rect=(0, 0, 0.83, 1))
    fig.legend(handles, labels, fontsize=7, loc="center right")
    fig.savefig(path, dpi=72)
    plt.close(fig)


def draw_sweep(points: list[SweepPoint], q: str, path: Path) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.4))
    cvs = [p.cv for p in points]
    for which, ax in enumerate(axes):
        for label in points[0].methods:
            colour, marker = STYLE[label]
            y = [max(errors(p.methods[label].stats[q], p.ref.stats[q], "flow_stress",
                            "H")[which], 1e-7) for p in points]
            ax.loglog(cvs, y, color=colour, marker=marker, ms=4, lw=0.9, label=label)
        noise = [ref_rel_stderr(p.ref.stats[q], "flow_stress", "H")[which] for p in points]
        ax.loglog(cvs, noise, color="0.6", ls="--", lw=0.8, label="reference's stderr")
        for level in (0.01, 0.05):
            ax.axhline(level, color="0.8", lw=0.6)
        _label_panel(ax, "C.V. of every JC input", q, which)
    _finish(plt, fig, axes[0], path)


# ------------------------------------------------------------------------------ tables

def error_table(main: Main, cfg: Config) -> str:
    qs = list(main.ref.stats)
    lines = ["| method | runs | wall (s, summed runs) | " + " | ".join(
        f"{q}: mean / var error" for q in qs) + " |", "|" + "---|" * (3 + len(qs))]
    lines.append(f"| reference (control-variate MC) | {main.ref.runs} | {main.ref.wall:.0f} | "
                 + " | ".join("± {:.2g} / ± {:.2g}".format(
                     *ref_rel_stderr(main.ref.stats[q], "flow_stress", "H")) for q in qs) + " |")
    for label, ests in main.curves.items():
        for e in ests:
            cells = []
            for q in qs:
                em, ev = errors(e.stats[q], main.ref.stats[q], "flow_stress", "H")
                cells.append(f"{em:.2g} / {ev:.2g}")
            lines.append(f"| {label} | {e.runs} | {e.wall:.1f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def worst_table(main: Main) -> str:
    """Every output and probe: the cheapest estimate of each method family, worst point."""
    qs = list(main.ref.stats)
    lines = ["| method | runs | " + " | ".join(f"{q}: worst mean / var error (output, probe)"
                                             for q in qs) + " |", "|" + "---|" * (2 + len(qs))]
    for label, ests in main.curves.items():
        if not ests:
            continue
        e = ests[-1] if label not in ("MC sobol",) else ests[-2]
        cells = []
        for q in qs:
            worst = [(0.0, ""), (0.0, "")]
            for out in OUTPUTS:
                for probe in ("H", "I", "G", "K"):
                    if moment(main.ref.stats[q], out, "variance", probe) <= 0:
                        continue
                    for w, err in enumerate(errors(e.stats[q], main.ref.stats[q], out, probe)):
                        if err > worst[w][0]:
                            worst[w] = (err, f"{out} {probe}")
            cells.append(f"{worst[0][0]:.2g} ({worst[0][1]}) / {worst[1][0]:.2g} ({worst[1][1]})")
        lines.append(f"| {label} | {e.runs} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def cost_table(main: Main, plain_s: float, local_s: float) -> str:
    seed_mc = SEED_MC_RUNS * main.per_run
    lines = [f"Per-run time: median wall time of one plain realization in a dask worker "
             f"{main.per_run:.2f} s; the seed's {SEED_MC_RUNS:,}-sample Monte Carlo at that rate "
             f"= {seed_mc:,.0f} s (our per-run time × {SEED_MC_RUNS:,}, stated as such).", "",
             "| method | solver runs | wall time (s, summed over its runs) | speed-up against "
             f"{SEED_MC_RUNS:,} × per-run | in runs ({SEED_MC_RUNS:,} / runs) |",
             "|---|---|---|---|---|"]
    rows = [("reference: control-variate MC", main.ref)]
    for label, ests in main.curves.items():
        rows += [(label, e) for e in ests]
    for label, e in rows:
        wall = e.wall if label != "taylor-local" else local_s
        lines.append(f"| {label} | {e.runs} | {wall:.1f} | {seed_mc / wall:,.0f} | "
                     f"{SEED_MC_RUNS / e.runs:,.0f} |")
    lines.append(f"\n`taylor-local`'s row uses its in-process timing (d), {local_s:.2f} s; a "
                 f"plain run in that process took {plain_s:.2f} s.")
    return "\n".join(lines)


def sweep_table(points: list[SweepPoint]) -> str:
    qs = list(points[0].ref.stats)
    lines = ["| C.V. | method | runs | " + " | ".join(f"{q}: mean / var error (ref ± se)"
                                                     for q in qs) + " |",
             "|" + "---|" * (3 + len(qs))]
    for p in points:
        for label, e in p.methods.items():
            cells = []
            for q in qs:
                em, ev = errors(e.stats[q], p.ref.stats[q], "flow_stress", "H")
                sm, sv = ref_rel_stderr(p.ref.stats[q], "flow_stress", "H")
                cells.append(f"{em:.2g} / {ev:.2g} (± {sm:.1g} / {sv:.1g})")
            lines.append(f"| {p.cv:g} | {label} | {e.runs} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def leave_table(points: list[SweepPoint]) -> str:
    qs = list(points[0].ref.stats)
    lines = ["| method | " + " | ".join(f"{q}: mean 1 % / 5 %, var 1 % / 5 %" for q in qs)
             + " |", "|" + "---|" * (1 + len(qs))]
    for label in points[0].methods:
        cells = [f"{leaves(points, label, q, 0, 0.01)} / {leaves(points, label, q, 0, 0.05)}, "
                 f"{leaves(points, label, q, 1, 0.01)} / {leaves(points, label, q, 1, 0.05)}"
                 for q in qs]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def warning_kind(text: str) -> str:
    """A short name for a method warning, for the table of which fired where."""
    low = text.lower()
    for key, name in (("loo", "pce LOO error"), ("curvature", "taylor-local curvature"),
                      ("c.v.", "C.V. too large for Taylor"), ("step", "stencil step"),
                      ("fail", "failed realizations"), ("surrogate", "control surrogate"),
                      ("rho", "control ρ"), ("does not vary", "no variance")):
        if key in low:
            return name
    return text.split(":")[1].strip()[:40] if ":" in text else text[:40]


def warning_table(points: list[SweepPoint]) -> str:
    lines = ["| C.V. | method | warnings fired (kind: quantities) |", "|---|---|---|"]
    for p in points:
        for label, e in p.methods.items():
            kinds: dict[str, set] = {}
            for w in e.warnings:
                q, _, text = w.partition(": ")
                kinds.setdefault(warning_kind(text), set()).add(q)
            cell = "; ".join(f"{k}: {', '.join(sorted(v))}" for k, v in sorted(kinds.items()))
            lines.append(f"| {p.cv:g} | {label} | {cell or '—'} |")
    return "\n".join(lines)


# ------------------------------------------------------------------------------ main

def benchmark(scratch: Path, cfg: Config, reuse: bool, record: bool = True) -> dict:
    scratch.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    print(f"main comparison: resolution {cfg.resolution}, C.V. {cfg.cv}", flush=True)
    main = main_comparison(scratch, cfg, reuse)
    print("timing taylor-local against a plain run", flush=True)
    plain_s, local_s, plain_all, local_all = time_taylor_local(scratch, cfg)
    print("failure study", flush=True)
    failures = failure_study(scratch, cfg, reuse)
    points = sweep(scratch, cfg, reuse)
    checks = check_control_variate(main, cfg) + check_pce(main, cfg)
    ratio = local_s / plain_s
    checks.append(f"(c) cost: see the cost table; per-run {main.per_run:.2f} s, seed MC "
                  f"{SEED_MC_RUNS:,} × per-run = {SEED_MC_RUNS * main.per_run:,.0f} s")
    checks.append(f"(d) taylor-local: median of {cfg.timing_repeats} runs with sensitivities "
                  f"{local_s:.3f} s against {plain_s:.3f} s plain, ratio {ratio:.3f} "
                  f"({'≤' if ratio <= 1.2 else '>'} 1.2; runs "
                  f"{', '.join(f'{t:.2f}' for t in local_all)} / "
                  f"{', '.join(f'{t:.2f}' for t in plain_all)} s)")
    for line in checks + failures:
        print(line, flush=True)
    elapsed = time.perf_counter() - started
    out = dict(main=main, points=points, checks=checks, failures=failures, ratio=ratio,
               elapsed=elapsed)
    if not record:
        return out
    FIGURES.mkdir(parents=True, exist_ok=True)
    figures = []
    for q in main.ref.stats:
        tag = {"100 µs": "100us", "peak": "peak"}.get(q, "seed_time")
        draw_tradeoff(main, q, FIGURES / f"smpm_tradeoff_{tag}.png")
        figures.append(f"`docs/figures/smpm_tradeoff_{tag}.png` ({q})")
    draw_sweep(points, "100 µs", FIGURES / "smpm_tradeoff_cv_sweep.png")
    figures.append("`docs/figures/smpm_tradeoff_cv_sweep.png` (C.V. sweep, 100 µs)")
    body = f"""
Benchmark size, stated up front: example 2 (thin plate, JC A, B, C, n, m normal,
independent), outputs flow_stress, S11, S22 at H, I, G, K. Main comparison at **resolution
{cfg.resolution}** (8,400 particles), **C.V. {cfg.cv}**; C.V. sweep at **resolution
{cfg.sweep_resolution}** (2,100 particles). Reference: Monte Carlo with `control =
"taylor-local"` on {cfg.ref_samples} = {cfg.replicates} × {cfg.ref_samples // cfg.replicates}
scrambled Sobol' points + 1 control run ({main.ref.runs} runs), 2 dask workers, seed 1; its
standard errors come from its {cfg.replicates} replicates. Runs reused: plain Sobol' MC and
control-variate MC are nested whole-replicate prefixes of the reference, `pce` is fitted on
nested prefixes of the reference's samples (germ (x − μ)/σ of those points), plain random MC
on prefixes of its own {cfg.random_samples} i.i.d. runs (a prefix of an i.i.d. sample is one;
a random subset of the stratified Sobol' pool would not be), LHS on its own runs
({', '.join(map(str, cfg.lhs_sizes))}). A sub-sample shares runs with the reference, so its
error against it is the sub-sampling error, and plain Sobol' and `pce` at {cfg.ref_samples}
use the reference's very runs (their error there is the estimators' difference only);
control-variate prefixes stop at half the reference. Wall times are the workers' summed
per-run times under the load of the moment; the speed-up in runs does not depend on load. Seed-matched time {cfg.seed_time_us:g} µs (docs/mpm_scenes.md;
the seed-convention reading puts the seed's state at 8–10 µs). Peak: max |y| over time of
each realization; `taylor-local` and the control surrogate use the nominal run's
derivatives at its argmax time. Whole benchmark {elapsed:.0f} s wall on this machine; it ran
while other work loaded the machine (2 cores shared): the timing ratio (d) is measured in
one process, the accuracy figures do not depend on load.

**Checks** (benchmark figures of this command)

{chr(10).join('- ' + c for c in checks)}

**Cost** (per method; wall time = sum of its runs' wall times in the workers)

{cost_table(main, plain_s, local_s)}

**Error against the reference, σy at H** (relative: |mean/mean_ref − 1| / |var/var_ref −
1|; the reference row gives its own relative standard errors)

{error_table(main, cfg)}

**Worst over the 12 (output, probe) points** (largest estimate of each family below the
reference's size; points with zero reference variance skipped)

{worst_table(main)}

**C.V. sweep** (resolution {cfg.sweep_resolution}; per C.V. its own reference:
control-variate MC {cfg.sweep_ref_samples} = {cfg.replicates} × {cfg.sweep_ref_samples // cfg.replicates}
+ 1 runs, the same normal draws at every C.V.; `pce` order by LOO ≤ 3 on {cfg.sweep_pce_samples}
own Sobol' runs; control-variate MC on the reference's first {cfg.sweep_cv_samples} samples
+ its control run). σy at H:

{sweep_table(points)}

**Where each method leaves 1 % and 5 %** (smallest C.V. whose error of σy at H exceeds the
level and twice the reference's own standard error; "> 0.3": never in the sweep)

{leave_table(points)}

**Warnings that fired** (the methods' own warnings, per C.V.)

{warning_table(points)}

**A failed realization** (separate small studies at resolution {cfg.failure_resolution},
20 µs, jc.n with C.V. 1.5 so that some sampled n ≤ 0, which the solver refuses)

{chr(10).join('- ' + f for f in failures)}

Figures: {', '.join(figures)}.
"""
    write_section("smpm-tradeoff", "MPM: the speed–accuracy trade (issue 9)", body)
    print(body)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scratch", type=Path, default=Path("/tmp/smpm_tradeoff"))
    parser.add_argument("--reuse", action="store_true",
                        help="analyse existing result files instead of rerunning them")
    args = parser.parse_args()
    benchmark(args.scratch, Config(), args.reuse)


if __name__ == "__main__":
    main()
