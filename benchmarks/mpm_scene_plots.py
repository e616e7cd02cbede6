"""Particle plots of the seed's two contact-explosion scenes (seed 000, Figs. 4 and 8).

Runs the SMALL thin-plate and thick-plate scenes deterministically (nominal parameters) to
their end time (100 us) and draws the particles coloured by material, by pressure p* (at the
peak-pressure time near the plate and at the end) and by equivalent plastic strain (end),
into docs/figures/mpm_thin_plate_particles.png and docs/figures/mpm_thick_plate_particles.png.
Prints the numbers quoted in docs/mpm_scenes.md (probe peaks, end values, plate maxima).

The scene is the one the studies use: the inline `[scene]` table of
studies/smpm_jc_thin_plate.toml / studies/smpm_eos_thick_plate.toml (the `_small` scene with
its cropped sides as walls; see docs/mpm_scenes.md).

The solver exposes no particle snapshot (`MPMSolver.run` returns probe series and energy
history only), so this script drives the solver's internal `_Run` object itself — read-only:
it builds `_Run(solver, solver._parameters({}))`, wraps its probe recorder so that at chosen
output times it copies the particle positions and state rows, and calls `advance()`. Nothing
in solvers/ is changed; the run is the same time loop `MPMSolver.run` uses.

    python benchmarks/mpm_scene_plots.py [--resolution 1.0] [--snap-us 10 100]
    python benchmarks/mpm_scene_plots.py --compare    # no runs: Taylor vs MC vs seed tables
    python benchmarks/mpm_scene_plots.py --compare --cv 0.15 --thin T.nc MC.nc --thick T.nc MC.nc

`--compare` reads results/smpm_{jc_thin,eos_thick}_plate{,_mc}.nc (written by `uqflow run`
on the four studies) and prints the probes' mean and variance by Taylor and by Monte Carlo
beside the seed's Tables 6-8 (tests/data/seed_tables.toml, converted from 1e-2 Mbar = 1 GPa
and 1e-6 Mbar^2 = 1e-2 GPa^2), at the end time and averaged over the time series. It then
measures the Taylor means against the Monte Carlo error bars the result file reports (for
the scrambled Sobol' studies: randomized QMC, 8 replicates, 7 degrees of freedom), beside the
i.i.d. formula s/sqrt(n) on the same points, and the replicates' error of the MC variance.
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from solvers.mpm import MPMSolver  # noqa: E402
from solvers.mpm import solver as _solver_mod  # noqa: E402
from solvers.mpm.materials import state as ST  # noqa: E402

FIGURES = ROOT / "docs" / "figures"
SCENES = {
    "thin": ROOT / "studies" / "smpm_jc_thin_plate.toml",
    "thick": ROOT / "studies" / "smpm_eos_thick_plate.toml",
}
TITLES = {"thin": "example 2: thin plate (0.02 m)", "thick": "example 1: thick plate (0.06 m)"}


class _SnapRecorder:
    """Proxy of the run's ProbeRecorder: records as usual, and copies the particles at the
    output indices in `want`."""

    def __init__(self, inner, want):
        self.inner = inner
        self.want = set(want)
        self.snaps = {}

    def record(self, k, run):
        self.inner.record(k, run)
        if k in self.want:
            self.snaps[k] = (run.x.copy(), run.y.copy(), run.S.copy())

    def __getattr__(self, name):
        return getattr(self.inner, name)


def run_scene(scene: dict, snap_times_s):
    solver = MPMSolver.from_scene(scene)
    times = solver.times
    want = sorted({int(np.argmin(np.abs(times - t))) for t in snap_times_s})
    run = _solver_mod._Run(solver, solver._parameters({}))
    rec = _SnapRecorder(run.recorder, want)
    run.recorder = rec
    t0 = time.perf_counter()
    run.advance()
    wall = time.perf_counter() - t0
    ds = solver._template.copy(deep=True)
    for name, arr in rec.inner.results().items():
        ds[name].values[...] = arr
    parts = solver.parts
    labels = list(solver.labels)
    return solver, ds, {float(times[k]): v for k, v in rec.snaps.items()}, parts, labels, \
        run, wall


_LOADED = {}

#: Two-sided level of the Taylor-vs-MC agreement test: that of "within 3 standard errors" for a
#: normal error (99.73 %). With R = 8 scrambled replicates the RQMC error has R - 1 = 7
#: degrees of freedom, so the same level needs the Student t quantile (4.53), not 3.
AGREEMENT_LEVEL = 0.9973


def _load(path, group):
    import xarray as xr
    key = (str(path), group)
    if key not in _LOADED:
        with xr.open_dataset(path, group=group) as f:
            _LOADED[key] = f.load()
    return _LOADED[key]


def _stats(path, out):
    ds = _load(path, "statistics")
    y = ds[out]
    return (y.sel(statistic="mean"), y.sel(statistic="variance"), ds)


class MonteCarloErrors:
    """The error bars of one Monte Carlo output, from the result file.

    `stderr` is the standard error the study reported (`statistic = "stderr"`: for the
    scrambled Sobol' studies the spread of the R replicate means / sqrt(R)), `dof` its degrees
    of freedom. `iid` is the i.i.d. formula s/sqrt(n) on the same points, which uqflow used for
    Sobol' points before randomized QMC. `variance_rel_error` is the relative standard error
    of the MC variance, also from the replicates: the spread of the R within-replicate
    variances / sqrt(R), divided by their mean."""

    def __init__(self, path, out):
        stats = _load(path, "statistics")
        runs = _load(path, "runs")
        self.kind = stats.attrs.get("stderr_kind", "iid")
        self.dof = int(stats.attrs["degrees_of_freedom"])
        self.replicates = int(stats.attrs.get("replicates", 0)) or None
        self.stderr = stats[out].sel(statistic="stderr").values
        ok = np.asarray(runs["status"].values == "ok")
        y = runs[out].values[ok]
        self.samples = y.shape[0]
        self.iid = y.std(axis=0, ddof=1) / np.sqrt(self.samples)
        self.variance_rel_error = np.full(self.stderr.shape, np.nan)
        if self.replicates:
            which = np.flatnonzero(ok) % self.replicates
            within = np.stack([y[which == r].var(axis=0, ddof=1)
                               for r in range(self.replicates) if np.sum(which == r) > 1])
            with np.errstate(divide="ignore", invalid="ignore"):
                self.variance_rel_error = (within.std(axis=0, ddof=1) / np.sqrt(len(within))
                                           / within.mean(axis=0))

    def level(self, multiple):
        """How often `multiple` standard errors hold the exact mean (Student t, `dof`)."""
        import scipy.stats as sps
        return float(1.0 - 2.0 * sps.t.sf(multiple, self.dof))

    def quantile(self, level=AGREEMENT_LEVEL):
        """The multiple of `stderr` that holds the exact mean with probability `level`."""
        import scipy.stats as sps
        return float(sps.t.ppf(0.5 + level / 2, self.dof))


def linear_output_error_ratio(points_per_replicate):
    """RQMC / i.i.d. standard error of the mean of an output linear in one normal input.

    Every one-dimensional projection of a scrambled Sobol' replicate of m = 2^k points puts
    one point in each of m equal-probability strata, so the mean of Z ~ N(0, 1) keeps only
    the within-stratum variance: sum over strata of p Var(Z | stratum), p = 1/m, with
    E[Z | a < Z < b] = (phi(a) - phi(b)) / p and E[Z^2 | .] = 1 + (a phi(a) - b phi(b)) / p.
    The ratio of standard errors is the square root of that share of Var(Z) = 1."""
    import scipy.stats as sps
    m = points_per_replicate
    edges = sps.norm.ppf(np.linspace(0.0, 1.0, m + 1))
    phi = sps.norm.pdf(edges)
    with np.errstate(invalid="ignore"):         # the outer edges: -inf * 0, +inf * 0 -> 0
        a_phi = np.where(np.isfinite(edges), edges * phi, 0.0)
    first = (phi[:-1] - phi[1:]) * m
    second = 1.0 + (a_phi[:-1] - a_phi[1:]) * m
    return float(np.sqrt(np.sum((second - first**2) / m)))


def _agreement(taylor_mean, mc_mean, err: MonteCarloErrors, unit=1e-9):
    """How far the Taylor mean (time, probe) lies from the MC mean, in MC errors."""
    gap = np.abs(taylor_mean.values - mc_mean.values)
    spread = err.stderr > 0                  # before the load arrives every run is identical
    k = err.quantile()
    ratio = err.stderr[spread] / err.iid[spread]
    print(f"    all {gap.size} (time, probe) points, {int(spread.sum())} with MC spread: "
          f"median |Taylor - MC| mean {np.median(gap) * unit:.4f}, largest "
          f"{gap.max() * unit:.4f}; median MC stderr {np.median(err.stderr[spread]) * unit:.4f} "
          f"({err.kind}, {err.dof} dof), i.i.d. s/sqrt(n) {np.median(err.iid[spread]) * unit:.4f}"
          f", ratio median {np.median(ratio):.2f} [{np.quantile(ratio, 0.1):.2f} .. "
          f"{np.quantile(ratio, 0.9):.2f}] (10-90 %)")
    print(f"    within {k:.2f} stderr (t{err.dof} at {100 * AGREEMENT_LEVEL:.2f} %): "
          f"{100 * np.mean(gap[spread] <= k * err.stderr[spread]):.1f} %; within 3 stderr (t{err.dof} "
          f"at {100 * err.level(3.0):.1f} %) "
          f"{100 * np.mean(gap[spread] <= 3 * err.stderr[spread]):.1f} %; within 3 i.i.d. "
          f"s/sqrt(n) {100 * np.mean(gap[spread] <= 3 * err.iid[spread]):.1f} %; "
          f"median |Taylor - MC| / stderr {np.median(gap[spread] / err.stderr[spread]):.2f}")
    i, j = np.unravel_index(int(np.argmax(gap)), gap.shape)
    outside = spread & (gap > k * err.stderr)
    print(f"    largest |Taylor - MC| at {taylor_mean['time'].values[i] * 1e6:.1f} us, probe "
          f"{taylor_mean['probe'].values[j]}: {gap[i, j] / err.stderr[i, j]:.1f} stderr; points "
          f"outside {k:.2f} stderr at {len(np.unique(np.nonzero(outside)[0]))} of "
          f"{gap.shape[0]} output times")


def compare(cv=0.10, thin=None, thick=None):
    res = ROOT / "results"
    seed = tomllib.load(open(ROOT / "tests" / "data" / "seed_tables.toml", "rb"))["smpm"]
    seed = seed["example2_jc"]   # the tables sit under [smpm.example2_jc] in TOML terms
    tables = {"flow_stress": seed["table6_flow_stress"], "S11": seed["table7_S11"],
              "S22": seed["table8_S22"]}
    thin_t, thin_m = map(Path, thin or (res / "smpm_jc_thin_plate.nc",
                                         res / "smpm_jc_thin_plate_mc.nc"))
    if thin_t.exists() and thin_m.exists():
        n_mc = MonteCarloErrors(thin_m, "flow_stress").samples
        print(f"thin plate, JC C.V. {cv:g} (GPa, GPa^2): seed MC / seed SMPM | ours "
              f"MC({n_mc}) / Taylor, at 100 us; [time-mean over 0-100 us]")
        for out, rows in tables.items():
            mt, vt, dt_ = _stats(thin_t, out)
            mm, vm, _ = _stats(thin_m, out)
            for probe, row_cv, smc, ssm, svmc, svsm in rows:
                if abs(cv - row_cv) > 1e-9:
                    continue
                a = lambda v: float(v.sel(probe=probe).isel(time=-1)) * 1e-9  # noqa: E731
                b = lambda v: float(v.sel(probe=probe).mean("time")) * 1e-9  # noqa: E731
                a2 = lambda v: float(v.sel(probe=probe).isel(time=-1)) * 1e-18  # noqa: E731
                b2 = lambda v: float(v.sel(probe=probe).mean("time")) * 1e-18  # noqa: E731
                print(f"  {out:11s} {probe}: mean seed {smc:7.4f}/{ssm:7.4f} | ours "
                      f"{a(mm):7.4f}/{a(mt):7.4f} [{b(mm):7.4f}/{b(mt):7.4f}]   var seed "
                      f"{svmc * 1e-2:.2e}/{svsm * 1e-2:.2e} | ours {a2(vm):.2e}/{a2(vt):.2e} "
                      f"[{b2(vm):.2e}/{b2(vt):.2e}]")
        err = MonteCarloErrors(thin_m, "flow_stress")
        if err.replicates:
            per = err.samples // err.replicates
            print(f"  MC: {err.replicates} scrambled replicates of {per} points; an output "
                  f"linear in normal inputs would have RQMC / i.i.d. standard error "
                  f"{linear_output_error_ratio(per):.3f} (stratification alone)")
        print("  Taylor against MC, with the MC error bars as reported (GPa):")
        for out in tables:
            mt, vt, _ = _stats(thin_t, out)
            mm, vm, _ = _stats(thin_m, out)
            err = MonteCarloErrors(thin_m, out)
            print(f"  {out}:")
            _agreement(mt, mm, err)
            std_t = np.sqrt(vt.values).mean(axis=0)
            std_m = np.sqrt(vm.values).mean(axis=0)
            print("    time-mean std per probe, Taylor / MC: " + ", ".join(
                f"{p} {a * 1e-9:.4f}/{b * 1e-9:.4f} ({100 * (a / b - 1):+.0f} %)"
                for p, a, b in zip(mt["probe"].values, std_t, std_m)))
            print(f"    largest std over all points, Taylor / MC: "
                  f"{np.sqrt(vt.values.max()) * 1e-9:.4f} / {np.sqrt(vm.values.max()) * 1e-9:.4f}"
                  f"; median std over all points {np.median(np.sqrt(vt.values)) * 1e-9:.4f} / "
                  f"{np.median(np.sqrt(vm.values)) * 1e-9:.4f}")
            end = -1
            print("    at 100 us per probe: MC stderr, (Taylor - MC) / stderr, Taylor var / MC "
                  "var - 1, rel. stderr of the MC var (replicates): " + ", ".join(
                      f"{p} {err.stderr[end, j] * 1e-9:.4f} "
                      f"{(mt.values[end, j] - mm.values[end, j]) / err.stderr[end, j]:+.2f} "
                      f"{100 * (vt.values[end, j] / vm.values[end, j] - 1):+.0f} % "
                      f"{100 * err.variance_rel_error[end, j]:.0f} %"
                      for j, p in enumerate(mt["probe"].values)))
            spread = err.stderr > 0
            print(f"    MC variance, rel. stderr from the replicates: median "
                  f"{100 * np.nanmedian(err.variance_rel_error[spread]):.0f} % over the points "
                  f"with spread (the i.i.d. sqrt(2/(n-1)) would be "
                  f"{100 * np.sqrt(2 / (err.samples - 1)):.0f} %)")
        mt, vt, _ = _stats(thin_t, "plastic_strain")
        mm, vm, _ = _stats(thin_m, "plastic_strain")
        for probe in mt["probe"].values:
            print(f"  plastic_strain {probe}: end mean MC {float(mm.sel(probe=probe)[-1]):.4f} "
                  f"Taylor {float(mt.sel(probe=probe)[-1]):.4f}; std MC "
                  f"{float(vm.sel(probe=probe)[-1]) ** 0.5:.4f} Taylor "
                  f"{float(vt.sel(probe=probe)[-1]) ** 0.5:.4f}")
    thick_t, thick_m = map(Path, thick or (res / "smpm_eos_thick_plate.nc",
                                           res / "smpm_eos_thick_plate_mc.nc"))
    if thick_t.exists() and thick_m.exists():
        print("thick plate, EOS (C.V. of the files): pressure p* (GPa); the seed gives only figures")
        mt, vt, dt_ = _stats(thick_t, "pressure")
        mm, vm, _ = _stats(thick_m, "pressure")
        err = MonteCarloErrors(thick_m, "pressure")
        t = mt["time"].values * 1e6
        for j, probe in enumerate(mt["probe"].values):
            m1 = mt.sel(probe=probe).values * 1e-9
            k = int(np.argmax(m1))
            s1 = np.sqrt(vt.sel(probe=probe).values) * 1e-9
            s2 = np.sqrt(vm.sel(probe=probe).values) * 1e-9
            m2 = mm.sel(probe=probe).values * 1e-9
            se = err.stderr[:, j] * 1e-9
            print(f"  {probe}: peak mean Taylor {m1[k]:.3f} MC {m2[k]:.3f} at {t[k]:.1f} us; "
                  f"std there Taylor {s1[k]:.4f} MC {s2[k]:.4f}; max std over time Taylor "
                  f"{s1.max():.4f} MC {s2.max():.4f}; time-mean |mean diff| "
                  f"{np.mean(np.abs(m1 - m2)) * 1e3:.3f} MPa, largest "
                  f"{np.max(np.abs(m1 - m2)) * 1e3:.3f} MPa; time-mean std Taylor {s1.mean():.4f} "
                  f"MC {s2.mean():.4f}; MC stderr at the peak {se[k]:.5f} "
                  f"(i.i.d. {err.iid[k, j] * 1e-9:.5f}), time-mean {se.mean():.5f} "
                  f"(i.i.d. {err.iid[:, j].mean() * 1e-9:.5f})")
        _agreement(mt, mm, err)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=float, default=1.0)
    ap.add_argument("--snap-us", type=float, nargs="+", default=[10.0, 100.0],
                    help="output times (us) of the pressure snapshots; the last is the end")
    ap.add_argument("--only", choices=list(SCENES), default=None)
    ap.add_argument("--compare", action="store_true",
                    help="no runs: print Taylor vs MC vs the seed's tables from results/")
    ap.add_argument("--cv", type=float, default=0.10,
                    help="with --compare: the seed's rows of this C.V. (0.10 or 0.15)")
    ap.add_argument("--thin", nargs=2, metavar=("TAYLOR_NC", "MC_NC"), default=None,
                    help="with --compare: other thin-plate result files")
    ap.add_argument("--thick", nargs=2, metavar=("TAYLOR_NC", "MC_NC"), default=None,
                    help="with --compare: other thick-plate result files")
    args = ap.parse_args(argv)
    if args.compare:
        compare(args.cv, args.thin, args.thick)
        return
    FIGURES.mkdir(parents=True, exist_ok=True)
    for key, study in SCENES.items():
        if args.only and key != args.only:
            continue
        scene = tomllib.load(open(study, "rb"))["scene"]
        if isinstance(scene, str):       # the studies name their scene file
            scene = tomllib.load(open(study.parent / scene, "rb"))
        scene["resolution"] = args.resolution
        snaps_s = [t * 1e-6 for t in args.snap_us]
        solver, ds, snaps, parts, labels, run, wall = run_scene(scene, snaps_s)
        print(f"== {key} plate ({study.name} scene, resolution {args.resolution}): "
              f"{run.x.size} particles, {run.step_no} steps, {wall:.1f} s")
        mat = parts.material
        steel = labels.index("steel")
        # probe series
        t_us = ds["time"].values * 1e6
        for q in ("pressure", "flow_stress", "plastic_strain", "S11", "S22"):
            if q not in ds:
                continue
            for j, name in enumerate(ds["probe"].values):
                s = ds[q].values[:, j]
                k = int(np.nanargmax(np.abs(s)))
                unit, f = ("GPa", 1e-9) if q != "plastic_strain" else ("", 1.0)
                print(f"  {q:15s} {name}: peak |.| {s[k] * f:9.4f} {unit} at {t_us[k]:5.1f} us;"
                      f" end {s[-1] * f:9.4f} {unit}")
        tlist = sorted(snaps)
        t_end = tlist[-1]
        x, y, S = snaps[t_end]
        ps = mat == steel
        print(f"  plate at {t_end * 1e6:.0f} us: max plastic strain {S[ps, ST.EPS_P].max():.3f}, "
              f"max flow stress {S[ps, ST.SY].max() * 1e-9:.3f} GPa, "
              f"max |p| {np.abs(S[ps, ST.P]).max() * 1e-9:.3f} GPa")
        for t in tlist:
            xs, ys, Ss = snaps[t]
            print(f"  t = {t * 1e6:5.1f} us: max p all {Ss[:, ST.P].max() * 1e-9:.2f} GPa, "
                  f"in plate {Ss[ps, ST.P].max() * 1e-9:.2f} GPa, "
                  f"in water {Ss[mat == labels.index('water'), ST.P].max() * 1e-9:.2f} GPa")

        # ---- figure: material (end), pressure at each snapshot, plastic strain (end) ----
        n = 2 + len(tlist)
        fig, axes = plt.subplots(1, n, figsize=(3.6 * n, 3.9), constrained_layout=True)
        dom = scene["domain"]
        ms = max(0.3, 1.2 / args.resolution)

        def frame(ax, title):
            ax.set_xlim(*dom["x"])
            ax.set_ylim(*dom["y"])
            ax.set_aspect("equal")
            ax.set_xlabel("x (m)")
            ax.set_title(title, fontsize=9)

        ax = axes[0]
        colors = np.array([[0.85, 0.35, 0.1], [0.35, 0.35, 0.4], [0.55, 0.75, 0.95]])
        cmap_mat = {labels.index("tnt"): 0, steel: 1, labels.index("water"): 2}
        cidx = np.array([cmap_mat[int(m)] for m in range(len(labels))])[mat]
        ax.scatter(x, y, s=ms, c=colors[cidx], lw=0, rasterized=True)
        frame(ax, f"material, t = {t_end * 1e6:.0f} µs\n(orange TNT, grey steel, blue water)")
        ax.set_ylabel("y (m)")
        for t, ax in zip(tlist, axes[1:]):
            xs, ys, Ss = snaps[t]
            p = Ss[:, ST.P] * 1e-9
            vmax = max(float(np.percentile(np.abs(p), 99.5)), 1e-3)
            sc = ax.scatter(xs, ys, s=ms, c=p, cmap="coolwarm", vmin=-vmax, vmax=vmax, lw=0,
                            rasterized=True)
            fig.colorbar(sc, ax=ax, shrink=0.8, label="p* (GPa)")
            frame(ax, f"pressure p*, t = {t * 1e6:.0f} µs")
        ax = axes[-1]
        ax.scatter(x[~ps], y[~ps], s=ms, c="0.9", lw=0, rasterized=True)
        sc = ax.scatter(x[ps], y[ps], s=ms * 1.5, c=S[ps, ST.EPS_P], cmap="viridis", lw=0,
                        rasterized=True)
        fig.colorbar(sc, ax=ax, shrink=0.8, label="plastic strain")
        for j, name in enumerate(ds["probe"].values):
            px = ds["position_x"].values[-1, j] if "position_x" in ds else None
            if px is not None:
                ax.plot(px, ds["position_y"].values[-1, j], "r+", ms=6)
        frame(ax, f"equivalent plastic strain (steel), t = {t_end * 1e6:.0f} µs")
        fig.suptitle(f"Seed 000 {TITLES[key]}, small scene, dx = "
                     f"{scene['cell_size'] / args.resolution * 1e3:g} mm, nominal parameters",
                     fontsize=10)
        out = FIGURES / f"mpm_{key}_plate_particles.png"
        fig.savefig(out, dpi=130)
        plt.close(fig)
        print(f"  wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
