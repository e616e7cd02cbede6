"""What MPM results add to ``uqflow report`` and ``uqflow run``: the scene map, and the
comparison of several results of one scene in the layout of seed 000's Tables 6-8 and 3/9.

``report(trees, folder, figures=True, time=None, reference=None) -> (text, pngs)`` writes
``scene_map.png`` (scene_map.py: every body, material and probe) for the results' scene, and
compares the results (different methods: ``monte-carlo`` plain or with a control variate,
``taylor``, ``taylor-local``, ``pce``, any method whose statistics carry ``mean`` and
``variance``):

- prints the seed's **Tables 6-8 layout**: for every probe output (flow stress, S11, S22,
  pressure p*, ...), probe and C.V., each result's mean and variance at one output time,
  against the **reference** (the Monte Carlo result with the smallest standard error, see
  ``choose_reference``) with the relative errors and the reference's own uncertainty, and the
  seed's numbers (Tables 6-8, converted to SI) where output, probe and C.V. match;
- prints the seed's **Tables 3/9 layout**: solver runs, failed runs, solver time, per-run
  time and the speed-up against a 10,000-sample Monte Carlo at our per-run time, beside the
  seed's timings;
- draws for every (output, probe) the mean and variance over time, one line per result,
  the reference's band (mean ± 2 standard errors, variance ± 2 standard errors of the
  variance) shaded; one row of panels per C.V. Labels are in words: "deviatoric stress s_xx
  [GPa]", "probe H (x = 45, y = 0 mm)", times in µs (docs/mpm_report.md, "Labels").

Seed 000 is named only where its numbers are printed beside ours (``SEED_LINE`` says what it
is). The rules (reference, time, error formulas) are in docs/mpm_report.md. The seed's
numbers come from ``data/seed_tables.toml`` (an exact copy of ``tests/data/seed_tables.toml``).
"""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
import warnings
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import xarray as xr

from solvers.mpm.probes import LABELS
from solvers.mpm.scene import PROBE_QUANTITIES, parse
from solvers.mpm.scene_map import probe_words, write_scene_map
from uqflow.errors import StudyError
from uqflow.layout import (COMPILE_TIME, FAILED_RUNS, INPUT_CV, LONG_NAME, METHOD,
                           METHOD_OPTIONS, REALIZATION, RUNS_GROUP, SOLVER_COMPILE_TIME,
                           SOLVER_DESCRIPTION, SOLVER_RUNS, SOLVER_WALL_TIME, STATISTIC,
                           STATISTIC_MEAN, STATISTIC_STD, STATISTIC_STDERR,
                           STATISTIC_VARIANCE,
                           STATISTICS_GROUP, STATUS, STATUS_FAILED, STATUS_OK, STATUS_PENDING,
                           STUDY_FILE, STUDY_NAME, STUDY_READ_FILES,
                           STUDY_TEXT, STUDY_TEXT_OMITTED, UNITS, WALL_TIME, WITH_SENSITIVITIES,
                           is_diagnostic)
from uqflow.report import (FigureWarning, ResultView, figure_path, grid, new_figure,
                           save_figure, scene_ran, seconds)

__all__ = ["report", "load_results", "seed_tables", "seed_moments", "seed_costs",
           "choose_reference", "table_time", "variance_error", "moments_tables", "cost_table",
           "draw_figures", "MPMResult", "MC_SAMPLES_COMPARED"]

#: What seed 000 is, said once wherever its numbers are compared.
SEED_LINE = "seed 000: stochastic MPM of contact explosions, Taylor vs Monte Carlo"
#: The seed's Monte Carlo sample count, against which every speed-up is stated.
MC_SAMPLES_COMPARED = 10_000
#: Seed Tables 6-8 give means in 1e-2 Mbar and variances in 1e-6 Mbar²; 1 Mbar = 1e11 Pa.
SEED_MEAN_UNIT_PA = 1e-2 * 1e11
SEED_VARIANCE_UNIT_PA2 = 1e-6 * 1e11 ** 2
#: Which seed table holds which output (our output names).
SEED_TABLE_OF_OUTPUT = {"flow_stress": "table6_flow_stress", "S11": "table7_S11",
                        "S22": "table8_S22"}
#: Two C.V.s are one group when they agree to this relative tolerance: the study files write
#: them to a few digits, and input_cv = std/mean carries only rounding beyond that.
CV_MATCH_RTOL = 1e-9
#: Reference bands are mean ± BAND_WIDTH standard errors (≈ 95 % for a normal error).
BAND_WIDTH = 2.0


# ------------------------------------------------------------------------------ seed numbers

def seed_tables() -> dict:
    """The ``[smpm]`` table of the seed numbers (package data ``data/seed_tables.toml``, an
    exact copy of ``tests/data/seed_tables.toml``; that file if the copy is missing)."""
    try:
        text = (resources.files("solvers.mpm") / "data" / "seed_tables.toml").read_text(
            encoding="utf-8")
    except (FileNotFoundError, OSError):
        text = (Path(__file__).resolve().parents[2] / "tests" / "data"
                / "seed_tables.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)["smpm"]


@dataclass(frozen=True)
class SeedMoments:
    """One row of seed Tables 6-8 in SI units (Pa, Pa²)."""
    mc_mean: float
    smpm_mean: float
    mc_variance: float
    smpm_variance: float


def seed_moments(output: str) -> dict[tuple[str, float], SeedMoments]:
    """Seed Table 6, 7 or 8 for ``output`` as {(probe, C.V.): SeedMoments}, converted from
    1e-2 Mbar (= 1 GPa) and 1e-6 Mbar² (= 1e-2 GPa²) to Pa and Pa²; {} for other outputs."""
    key = SEED_TABLE_OF_OUTPUT.get(output)
    if key is None:
        return {}
    rows = {}
    for probe, cv, mc_mean, smpm_mean, mc_var, smpm_var in seed_tables()["example2_jc"][key]:
        rows[(str(probe), float(cv))] = SeedMoments(
            mc_mean * SEED_MEAN_UNIT_PA, smpm_mean * SEED_MEAN_UNIT_PA,
            mc_var * SEED_VARIANCE_UNIT_PA2, smpm_var * SEED_VARIANCE_UNIT_PA2)
    return rows


@dataclass(frozen=True)
class SeedCost:
    example: str
    table: str
    cv: float
    smpm_seconds: float
    mc_seconds: float
    mc_samples: int

    @property
    def per_run_seconds(self) -> float:
        return self.mc_seconds / self.mc_samples

    @property
    def speedup(self) -> float:
        return self.mc_seconds / self.smpm_seconds


def seed_costs() -> dict[str, SeedCost]:
    """Seed Tables 3 (example 1, Mie-Grüneisen inputs) and 9 (example 2, Johnson-Cook)."""
    seed = seed_tables()
    n = int(seed["mc_samples"])
    ex1, ex2 = seed["example1_eos"]["time_s"], seed["example2_jc"]["time_s"]
    return {"eos": SeedCost("example 1", "Table 3", 0.01, ex1["smpm"], ex1["monte_carlo"], n),
            "jc": SeedCost("example 2", "Table 9", 0.1, ex2["smpm"], ex2["monte_carlo"], n)}


# ------------------------------------------------------------------------------ one result

@dataclass
class MPMResult:
    """One result file as the report reads it."""
    file: str
    name: str
    method: str
    label: str
    attrs: dict
    runs: xr.Dataset | None
    stats: xr.Dataset | None
    outputs: list[str]
    probes: list[str]
    times: np.ndarray
    parameters: tuple[str, ...]
    cv: float | None
    cv_text: str
    scene: tuple[str, str]          # (what, identity) of the scene
    words: str = ""                 # the method in words, for legends (its report hook's)

    @property
    def plain_monte_carlo(self) -> bool:
        return self.method == "monte-carlo" and self.stats is not None \
            and "control" not in self.stats.attrs

    def statistic(self, output: str, label: str) -> xr.DataArray | None:
        if self.stats is None or output not in self.stats:
            return None
        labels = self.stats[STATISTIC].values
        if label == STATISTIC_VARIANCE and label not in labels and STATISTIC_STD in labels:
            # methods that describe their draws by mean and std (subset simulation's level-0
            # samples, importance sampling's weighted moments) store no variance
            return self.stats[output].sel(statistic=STATISTIC_STD) ** 2
        if label not in labels:
            return None
        return self.stats[output].sel(statistic=label)

    def cost(self) -> tuple[int, int, float]:
        """Solver runs done, failed runs, solver seconds (from the statistics, else runs)."""
        source = self.stats.attrs if self.stats is not None else {}
        if SOLVER_RUNS in source:
            return (int(source[SOLVER_RUNS]), int(source.get(FAILED_RUNS, 0)),
                    float(source.get(SOLVER_WALL_TIME, math.nan)))
        if self.runs is None or STATUS not in self.runs:
            return 0, 0, math.nan
        status = np.asarray(self.runs[STATUS].values).astype(str)
        done = status != STATUS_PENDING
        wall = np.asarray(self.runs[WALL_TIME].values, float)[done] \
            if WALL_TIME in self.runs else np.array([np.nan])
        return int(done.sum()), int((status == STATUS_FAILED).sum()), float(np.nansum(wall))


def _file_of(tree: xr.DataTree) -> str:
    source = tree.encoding.get("source") if tree.encoding else None
    if source:
        return Path(source).name
    return str(tree.attrs.get(STUDY_FILE) or tree.attrs.get(STUDY_NAME) or "result")


def _scene_identity(attrs: dict) -> tuple[str, str]:
    """(what the scene is, its identity): a scene file by the sha256 of its text as the study
    read it, an inline scene table by the sha256 of its canonical JSON."""
    read = json.loads(str(attrs.get(STUDY_READ_FILES) or "{}"))
    if "scene" in read:
        path, sha = read["scene"]
        return f"scene file {path} (sha256 {sha[:12]})", sha
    try:
        scene = tomllib.loads(str(attrs.get(STUDY_TEXT, ""))).get("scene")
    except tomllib.TOMLDecodeError:
        scene = None
    if isinstance(scene, dict):
        sha = hashlib.sha256(json.dumps(scene, sort_keys=True, default=str).encode()).hexdigest()
        return f"inline scene table (sha256 {sha[:12]})", sha
    description = str(attrs.get(SOLVER_DESCRIPTION, "?"))
    return f"scene '{description}'", description


def scene_map(tree: xr.DataTree, folder: Path) -> tuple[list[Path], list[str]]:
    """``scene_map.png`` of the scene ``tree`` ran, in ``folder``; ([], [why not]) when the
    scene cannot be had or drawn (the rest of the report goes on)."""
    scene, where = scene_ran(tree.attrs)
    if scene is None:
        return [], [f"{_file_of(tree)}: no scene map: {where}"]
    try:
        cfg = parse(scene)
        return [write_scene_map(cfg, Path(folder), title=f"{where}")], []
    except Exception as exc:  # a map that cannot be drawn must not cost the report
        warnings.warn(f"figure scene_map.png not written: {type(exc).__name__}: {exc}",
                      FigureWarning, stacklevel=2)
        return [], [f"{_file_of(tree)}: no scene map: {type(exc).__name__}: {exc}"]


def _method_label(method: str, stats: xr.Dataset | None, options: dict) -> str:
    a = stats.attrs if stats is not None else {}
    if method == "monte-carlo":
        rule = a.get("rule", options.get("rule", "?"))
        n = a.get("samples_ok", options.get("samples", "?"))
        text = f"monte-carlo {rule} {n}"
        if a.get("control") and int(a.get("control_used", 1)):
            text += f" + control {a['control']}"
        return text
    if method == "taylor":
        return f"taylor order {a.get('order', options.get('order', '?'))}"
    if method == "pce":
        order = a.get("order", options.get("order", "?"))
        return f"pce order {order}"
    return method


def _method_words(tree: xr.DataTree, label: str) -> str:
    """The method in words as its report hook says it ("Monte Carlo, 8 runs, one-run Taylor
    as control variate"); the compact label where the method says nothing."""
    try:
        return ResultView(tree).method_report.description or label
    except Exception:  # a method's hook that fails must not cost the comparison
        return label


def _probe_outputs(ds: xr.Dataset | None, want_statistic: bool) -> list[str]:
    if ds is None:
        return []
    return [str(v) for v in ds.data_vars
            if "probe" in ds[v].dims and "time" in ds[v].dims and not is_diagnostic(ds[v])
            and (not want_statistic or STATISTIC in ds[v].dims)
            and (want_statistic or REALIZATION in ds[v].dims)]


def _common_cv(ds: xr.Dataset | None) -> tuple[float | None, str, tuple[str, ...]]:
    if ds is None or INPUT_CV not in ds:
        return None, "?", ()
    names = tuple(str(p) for p in ds["parameter"].values)
    cv = np.asarray(ds[INPUT_CV].values, float)
    finite = cv[np.isfinite(cv) & (cv > 0)]
    if finite.size == 0:
        return None, "0", names
    if np.allclose(finite, finite[0], rtol=CV_MATCH_RTOL, atol=0):
        return float(finite[0]), f"{finite[0]:.3g}", names
    return None, "mixed " + "/".join(f"{c:.3g}" for c in finite), names


def _read(tree: xr.DataTree) -> MPMResult:
    attrs = dict(tree.attrs)
    runs = tree[RUNS_GROUP].to_dataset() if RUNS_GROUP in tree.children else None
    stats = tree[STATISTICS_GROUP].to_dataset() if STATISTICS_GROUP in tree.children else None
    source = stats if stats is not None else runs
    if source is None or "probe" not in source.coords:
        raise StudyError("has no probe outputs (time, probe): not an MPM result",
                         file=_file_of(tree))
    method = str((stats.attrs.get(METHOD) if stats is not None else None)
                 or attrs.get(METHOD, "?"))
    try:
        options = json.loads(str(attrs.get(METHOD_OPTIONS) or "{}"))
    except json.JSONDecodeError:
        options = {}
    outputs = _probe_outputs(stats, True) if stats is not None else _probe_outputs(runs, False)
    cv, cv_text, parameters = _common_cv(source)
    label = _method_label(method, stats, options)
    return MPMResult(
        file=_file_of(tree), name=str(attrs.get(STUDY_NAME, "?")), method=method,
        label=label, attrs=attrs, runs=runs, stats=stats,
        outputs=outputs, probes=[str(p) for p in source["probe"].values],
        times=np.asarray(source["time"].values, float), parameters=parameters, cv=cv,
        cv_text=cv_text, scene=_scene_identity(attrs), words=_method_words(tree, label))


def load_results(trees) -> tuple[list[MPMResult], list[str], list[str]]:
    """The results, the outputs they all have, and notes on what is left out.

    Refused with a one-line ``StudyError`` naming the file: a result of another scene than
    the first, with other probes or output times, or with no probe output in common."""
    results = [_read(t) for t in trees]
    first = results[0]
    notes = []
    for res in results[1:]:
        if res.scene[1] != first.scene[1]:
            raise StudyError(f"{res.scene[0]} is not the {first.scene[0]} of {first.file}: "
                             f"results of different scenes are not compared", file=res.file,
                             key="scene")
        if res.probes != first.probes:
            raise StudyError(f"probes {res.probes} differ from {first.probes} of {first.file}",
                             file=res.file, key="probe")
        if res.times.shape != first.times.shape or not np.array_equal(res.times, first.times):
            raise StudyError(f"output times differ from those of {first.file}", file=res.file,
                             key="time")
    with_outputs = [r for r in results if r.outputs]
    common = list(with_outputs[0].outputs) if with_outputs else []
    for res in with_outputs[1:]:
        if not set(res.outputs) & set(common):
            raise StudyError(f"no output in common with the results before it (outputs "
                             f"{', '.join(res.outputs)} against {', '.join(common)} of "
                             f"{with_outputs[0].file} ...)", file=res.file, key="outputs")
        common = [o for o in common if o in res.outputs]
    for res in with_outputs:
        left = [o for o in res.outputs if o not in common]
        if left:
            notes.append(f"{res.file}: {', '.join(left)} not in every result: not compared")
    return results, common, notes


# ------------------------------------------------------------------------------ errors

def mean_error(res: MPMResult, output: str) -> xr.DataArray | None:
    """The standard error of the mean the result reports (``stderr``), None without one."""
    return res.statistic(output, STATISTIC_STDERR)


def variance_error(res: MPMResult, output: str) -> tuple[xr.DataArray | None, str]:
    """The standard error of the result's variance over (time, probe), and how it was had.

    * a result that reports it (``{output}_variance_stderr``: control-variate Monte Carlo);
    * plain randomized QMC (``stderr_kind = rqmc``, R replicates, realization i in replicate
      i mod R): the spread of the R within-replicate variances / sqrt(R);
    * plain i.i.d. Monte Carlo (random or LHS): sqrt((m4 - s⁴ (n-3)/(n-1)) / n) from the
      sample variance s² and fourth central moment m4 of the ok runs — the kurtosis-based
      formula, which for normal data is s² sqrt(2/(n-1));
    * otherwise None ("not available")."""
    if res.stats is None:
        return None, "no statistics"
    if f"{output}_variance_stderr" in res.stats:
        return res.stats[f"{output}_variance_stderr"], "reported by the method"
    if not res.plain_monte_carlo:
        return None, "not available"
    if res.runs is None or output not in res.runs or STATUS not in res.runs:
        return None, "not available (no runs)"
    ok = np.asarray(res.runs[STATUS].values).astype(str) == STATUS_OK
    y = np.asarray(res.runs[output].values, float)
    template = res.stats[output].isel(statistic=0, drop=True)
    kind = str(res.stats.attrs.get("stderr_kind", "iid"))
    if kind == "rqmc":
        r = int(res.stats.attrs.get("replicates", 0))
        which = np.flatnonzero(ok) % r if r else np.array([], int)
        y_ok = y[ok]
        within = [y_ok[which == k].var(axis=0, ddof=1) for k in range(r)
                  if np.sum(which == k) > 1]
        if len(within) < 2:
            return None, "not available (fewer than 2 replicates with 2 runs)"
        within = np.stack(within)
        err = within.std(axis=0, ddof=1) / math.sqrt(len(within))
        return template.copy(data=err), f"spread of {len(within)} replicate variances"
    y_ok = y[ok]
    n = y_ok.shape[0]
    if n < 4:
        return None, "not available (fewer than 4 ok runs)"
    centred = y_ok - y_ok.mean(axis=0)
    s2 = centred.var(axis=0, ddof=1)
    m4 = np.mean(centred ** 4, axis=0)
    err = np.sqrt(np.maximum((m4 - s2 ** 2 * (n - 3) / (n - 1)) / n, 0.0))
    return template.copy(data=err), f"kurtosis formula, {n} i.i.d. runs"


# ------------------------------------------------------------------------------ rules

def table_time(results: list[MPMResult], time: float | None) -> tuple[int, str]:
    """Index of the table's output time and the sentence that says which it is: the output
    time nearest ``time`` (seconds), by default the last output time."""
    times = results[0].times
    if time is None:
        return len(times) - 1, f"t = {times[-1] * 1e6:.4g} µs (the last output time)"
    k = int(np.argmin(np.abs(times - float(time))))
    return k, (f"t = {times[k] * 1e6:.4g} µs (the output time nearest the requested "
               f"{float(time) * 1e6:.4g} µs)")


def _score(res: MPMResult, outputs: list[str], k: int) -> float:
    """Median over outputs and probes of stderr / |mean| at time index ``k``."""
    ratios = []
    for out in outputs:
        se, mean = mean_error(res, out), res.statistic(out, STATISTIC_MEAN)
        if se is None or mean is None:
            continue
        s = np.asarray(se.isel(time=k).values, float)
        m = np.abs(np.asarray(mean.isel(time=k).values, float))
        use = np.isfinite(s) & np.isfinite(m) & (m > 0)
        ratios.extend((s[use] / m[use]).tolist())
    return float(np.median(ratios)) if ratios else math.inf


def choose_reference(group: list[MPMResult], outputs: list[str], k: int,
                     reference: str | None = None) -> MPMResult | None:
    """The reference of a group of results at one C.V.: the result named by ``reference``
    (file name or study name) if it is in the group; else the result with a standard error
    of the mean (Monte Carlo, plain or control-variate) whose median relative standard error
    stderr/|mean| over the outputs and probes at the table time is smallest; None if no
    result reports a standard error."""
    if reference is not None:
        for res in group:
            if reference in (res.file, res.name):
                return res
    scored = [(s, i) for i, res in enumerate(group)
              if res.stats is not None and math.isfinite(s := _score(res, outputs, k))]
    return group[min(scored)[1]] if scored else None


def _groups(results: list[MPMResult]) -> list[list[MPMResult]]:
    """Results grouped by their random inputs and C.V., in order of first appearance."""
    groups: list[list[MPMResult]] = []
    for res in results:
        for group in groups:
            other = group[0]
            same_cv = (res.cv is None and other.cv is None and res.cv_text == other.cv_text) \
                or (res.cv is not None and other.cv is not None
                    and math.isclose(res.cv, other.cv, rel_tol=CV_MATCH_RTOL))
            if other.parameters == res.parameters and same_cv:
                group.append(res)
                break
        else:
            groups.append([res])
    return groups


def input_family(parameters) -> str | None:
    """Which of the seed's examples a result's random inputs match: "jc" when every input is
    a Johnson–Cook parameter (example 2), "eos" when every one is a Mie–Grüneisen EOS
    parameter (example 1), else None. The one place that reads a parameter's model from its
    dotted name (``<material>.jc.<name>``, ``<material>.eos.<name>``), until the materials'
    parameter tables say it (docs/mpm_report.md, "Which seed rows")."""
    parameters = tuple(parameters)
    for family in ("jc", "eos"):
        if parameters and all(f".{family}." in p for p in parameters):
            return family
    return None


def _is_johnson_cook(res: MPMResult) -> bool:
    return input_family(res.parameters) == "jc"


def _seed_row(res: MPMResult, output: str, probe: str) -> SeedMoments | None:
    """The seed's Tables 6-8 row for this output, probe and C.V.: only for a study whose
    random inputs are Johnson-Cook parameters (the seed's example 2)."""
    if res.cv is None or not _is_johnson_cook(res):
        return None
    for (p, cv), row in seed_moments(output).items():
        if p == probe and math.isclose(cv, res.cv, rel_tol=CV_MATCH_RTOL):
            return row
    return None


# ------------------------------------------------------------------------------ formatting

def output_units(results: list[MPMResult], output: str) -> str:
    """The units of ``output``: from the statistics, else from the runs (which carry the
    solver template's attributes, so an unfinished result has them too), else the scene
    schema's table of probe quantities; "" only for an output none of them knows."""
    for res in results:
        for ds in (res.stats, res.runs):
            if ds is not None and output in ds and UNITS in ds[output].attrs:
                return str(ds[output].attrs[UNITS])
    return PROBE_QUANTITIES.get(output, ("",))[0]


def output_words(results: list[MPMResult], output: str) -> str:
    """The output in words ("deviatoric stress s_xx"): its ``long_name`` in the results, else
    the solver's label of it, else its name."""
    for res in results:
        for ds in (res.stats, res.runs):
            if ds is not None and output in ds and ds[output].attrs.get(LONG_NAME):
                return str(ds[output].attrs[LONG_NAME])
    return LABELS.get(output, output)


def probe_label(results: list[MPMResult], j: int) -> str:
    """"probe H (x = 45, y = 0 mm)" from the results' ``probe_x``, ``probe_y`` coordinates
    (m); "probe H" for a result without them."""
    res = results[0]
    name = res.probes[j]
    for ds in (res.stats, res.runs):
        if ds is not None and "probe_x" in ds.coords and "probe_y" in ds.coords:
            return probe_words(name, float(ds["probe_x"].values[j]),
                               float(ds["probe_y"].values[j]))
    return f"probe {name}"


def _scale(units: str) -> tuple[float, str, str]:
    """Divisor and printed units of means and variances: stresses in GPa and GPa²."""
    if units == "Pa":
        return 1e9, "GPa", "GPa²"
    return 1.0, units or "-", f"({units})²" if units else "-"


def _fmt(x: float, digits: int = 5) -> str:
    return "nan" if not np.isfinite(x) else f"{x:.{digits}g}"


def _rel(x: float, ref: float) -> float:
    return (x - ref) / abs(ref) if np.isfinite(x) and np.isfinite(ref) and ref != 0 \
        else math.nan


def _pct(r: float) -> str:
    return "-" if not np.isfinite(r) else f"{100 * r:+.3g} %"


def _value(da: xr.DataArray | None, k: int, j: int) -> float:
    return math.nan if da is None else float(da.isel(time=k, probe=j).values)


# ------------------------------------------------------------------------------ Tables 6-8

def moments_tables(results: list[MPMResult], outputs: list[str], time: float | None = None,
                   reference: str | None = None) -> str:
    """The seed's Tables 6-8 layout for every output (see the module docstring)."""
    k, when = table_time(results, time)
    groups = _groups(results)
    lines, refs = [], []
    for group in groups:
        ref = choose_reference(group, outputs, k, reference)
        refs.append(ref)
        several_input_sets = len({g[0].parameters for g in groups}) > 1
        what = ", ".join(group[0].parameters) if several_input_sets else ""
        lines.append(f"C.V. {group[0].cv_text}{' (' + what + ')' if what else ''}: reference "
                     + (f"{ref.file} ({ref.label})" if ref else
                        "none (no result reports a standard error of the mean)"))
    if reference is not None and not any(
            r is not None and reference in (r.file, r.name) for r in refs):
        lines.append(f"the requested reference '{reference}' is in no group: the rule chose")
    seeded = False
    for out in outputs:
        div, unit, unit2 = _scale(output_units(results, out))
        seed_name = {"table6_flow_stress": "Table 6", "table7_S11": "Table 7",
                     "table8_S22": "Table 8"}.get(SEED_TABLE_OF_OUTPUT.get(out), "")
        rows = []
        for group, ref in zip(groups, refs):
            for j, probe in enumerate(results[0].probes):
                rows += _moment_rows(group, ref, out, k, j, probe, div)
        with_seed = any(row[2] == "seed" for row in rows)
        seeded = seeded or with_seed
        lines += ["", f"{output_words(results, out)} ({out}) at {when}: mean [{unit}], "
                      f"variance [{unit2}]; 'vs ref' = relative error against the reference, "
                      f"(z) = difference in reference standard errors"
                      + (f"; rows 'seed': seed 000's {seed_name}" if with_seed else "")]
        lines += grid(["probe", "C.V.", "result", "method", "runs", "mean", "vs ref",
                       "variance", "vs ref"], rows, {4, 5, 6, 7, 8})
    if seeded:
        lines += ["", SEED_LINE, seed_difference_line(results[0].times[k])]
    return "\n".join(lines)


#: The section of docs/mpm_report.md that explains why the seed rows differ from ours.
SEED_DIFFERENCE_SECTION = "Why our numbers differ from the seed's"


def seed_difference_line(t: float) -> str:
    """The one line under the seed rows that says why they differ from ours, and where the
    docs explain it."""
    return (f"seed rows: the seed's Tables 6-8 are an early snapshot of a weakly yielded plate "
            f"in the seed's own conventions (JC rate in 1/µs, no rate clamp, no heating), ours "
            f"are at t = {t * 1e6:.4g} µs in this scene's conventions, so gaps of tens of "
            f"percent in the flow stress, and larger ones in S11 and S22, are expected and "
            f"not errors: docs/mpm_report.md, \"{SEED_DIFFERENCE_SECTION}\"")


def _moment_rows(group, ref, out, k, j, probe, div) -> list[list[str]]:
    rows = []
    ref_mean = _value(ref.statistic(out, STATISTIC_MEAN), k, j) if ref else math.nan
    ref_var = _value(ref.statistic(out, STATISTIC_VARIANCE), k, j) if ref else math.nan
    ref_se = _value(mean_error(ref, out), k, j) if ref else math.nan
    ref_var_err, how = variance_error(ref, out) if ref else (None, "")
    ref_var_se = _value(ref_var_err, k, j)
    for res in group:
        rows += _result_rows(res, ref, out, k, j, probe, div, ref_mean, ref_var, ref_se,
                             ref_var_se)
    seed = _seed_row(group[0], out, probe)
    if seed is not None:
        cv = group[0].cv_text
        n = f"{MC_SAMPLES_COMPARED:,}"
        rows.append([probe, cv, "seed", "Monte Carlo", n, _fmt(seed.mc_mean / div),
                     _pct(_rel(seed.mc_mean, ref_mean)), _fmt(seed.mc_variance / div ** 2, 4),
                     _pct(_rel(seed.mc_variance, ref_var))])
        rows.append([probe, cv, "seed", "SMPM", "1", _fmt(seed.smpm_mean / div),
                     _pct(_rel(seed.smpm_mean, ref_mean)),
                     _fmt(seed.smpm_variance / div ** 2, 4),
                     _pct(_rel(seed.smpm_variance, ref_var))])
    return rows


def _result_rows(res, ref, out, k, j, probe, div, ref_mean, ref_var, ref_se,
                 ref_var_se) -> list[list[str]]:
    """The row of one result; a control-variate result adds the row of its surrogate (the
    control's own answer: for taylor-local the seed's one-run method, its variance the
    quadratic's full one), which costs only the control runs."""
    rows = []
    runs, failed, _ = res.cost()
    mean = _value(res.statistic(out, STATISTIC_MEAN), k, j)
    var = _value(res.statistic(out, STATISTIC_VARIANCE), k, j)
    if res.stats is None:
        rows.append([probe, res.cv_text, res.file, res.label, f"{runs}",
                     "no statistics (study did not finish)", "", "", ""])
        return rows
    if res.statistic(out, STATISTIC_MEAN) is None:
        # FORM and SORM estimate a probability of failure, not the output's moments
        rows.append([probe, res.cv_text, res.file, res.label, f"{runs}",
                     "no moments (its report gives what it estimates)", "", "", ""])
        return rows
    if res is ref:
        mean_text = f"{_fmt(mean / div)} ± {_fmt(ref_se / div, 2)}"
        # no "± n/a": a variance without a standard error is printed alone (the notes say why)
        var_text = _fmt(var / div ** 2, 4) + (
            f" ± {_fmt(ref_var_se / div ** 2, 2)}" if np.isfinite(ref_var_se) else "")
        rows.append([probe, res.cv_text, res.file, res.label + " (ref)", f"{runs}",
                     mean_text, "-", var_text, "-"])
    else:
        z = (mean - ref_mean) / ref_se if np.isfinite(ref_se) and ref_se > 0 else math.nan
        vs_mean = _pct(_rel(mean, ref_mean)) + (f" ({z:+.2g})" if np.isfinite(z) else "")
        rows.append([probe, res.cv_text, res.file, res.label, f"{runs}", _fmt(mean / div),
                     vs_mean, _fmt(var / div ** 2, 4) if np.isfinite(var) else "-",
                     _pct(_rel(var, ref_var))])
    surrogate = res.stats.get(f"{out}_surrogate")
    if surrogate is not None:
        mean = _value(surrogate.sel(surrogate_statistic="mean"), k, j)
        var = _value(surrogate.sel(surrogate_statistic="variance"), k, j)
        z = (mean - ref_mean) / ref_se if np.isfinite(ref_se) and ref_se > 0 else math.nan
        rows.append([probe, res.cv_text, res.file,
                     f"  its control: {res.stats.attrs.get('control', '?')} surrogate",
                     f"{res.stats.attrs.get('control_runs', '?')}", _fmt(mean / div),
                     _pct(_rel(mean, ref_mean)) + (f" ({z:+.2g})" if np.isfinite(z) else ""),
                     _fmt(var / div ** 2, 4), _pct(_rel(var, ref_var))])
    return rows


def _reference_notes(results: list[MPMResult], outputs: list[str]) -> list[str]:
    notes = []
    for res in results:
        if res.stats is None:
            continue
        if mean_error(res, outputs[0]) is not None:
            how = res.stats.attrs.get("stderr_note") or res.stats.attrs.get("stderr_kind",
                                                                            "reported")
            notes.append(f"{res.file}: standard error of the mean: {how}; of the variance: "
                         f"{variance_error(res, outputs[0])[1]}")
    return notes


# ------------------------------------------------------------------------------ Tables 3/9

@dataclass(frozen=True)
class RunTimes:
    """The run times of one result's finished (ok or failed) runs. A run's time is its wall
    time less the part numba spent compiling (``compile_time``, recorded by the executor):
    the first runs of each worker process compile the kernels, which a 10,000-run Monte Carlo
    pays once, not per run. ``compile`` is None for a result from before compile times were
    recorded; its run times are then the wall times."""
    run: np.ndarray          # s, per finished run
    ok: np.ndarray           # bool, per finished run
    plain: np.ndarray        # bool, per finished run: run without sensitivities
    compile: np.ndarray | None

    @property
    def solver_time(self) -> float:
        return float(np.nansum(self.run)) if self.run.size else math.nan

    @property
    def median_ok(self) -> float:
        ok = self.run[self.ok & np.isfinite(self.run)]
        return float(np.median(ok)) if ok.size else math.nan

    @property
    def per_run(self) -> float:
        """The per-run time of the header's definition (``_per_run_baseline``): the median of
        the plain ok runs, of every ok run when all ran with sensitivities."""
        plain = self.run[self.ok & self.plain & np.isfinite(self.run)]
        return float(np.median(plain)) if plain.size else self.median_ok

    @property
    def compile_time(self) -> float:
        return math.nan if self.compile is None else float(np.nansum(self.compile))


def run_times(res: MPMResult) -> RunTimes | None:
    """The result's run times from its runs; None without runs or wall times."""
    runs = res.runs
    if runs is None or WALL_TIME not in runs or STATUS not in runs:
        return None
    status = np.asarray(runs[STATUS].values).astype(str)
    done = status != STATUS_PENDING
    wall = np.asarray(runs[WALL_TIME].values, float)[done]
    compile_ = None
    if COMPILE_TIME in runs:
        recorded = np.asarray(runs[COMPILE_TIME].values, float)[done]
        if np.all(np.isfinite(recorded)):
            compile_ = recorded
    flagged = np.asarray(runs[WITH_SENSITIVITIES].values, bool)[done] \
        if WITH_SENSITIVITIES in runs else np.zeros(wall.size, bool)
    return RunTimes(run=wall - compile_ if compile_ is not None else wall,
                    ok=status[done] == STATUS_OK, plain=~flagged, compile=compile_)


def _per_run_baseline(results: list[MPMResult]) -> tuple[float, str]:
    """Our per-run time: the median run time (wall − compile) of the ok plain solver runs
    (realizations run without sensitivities) over all results; with none, of every ok run."""
    plain, every = [], []
    for res in results:
        times = run_times(res)
        if times is None:
            continue
        plain.extend(times.run[times.ok & times.plain].tolist())
        every.extend(times.run[times.ok].tolist())
    if plain:
        return float(np.median(plain)), f"median run time of the {len(plain)} plain ok runs"
    if every:
        return float(np.median(every)), (f"median run time of the {len(every)} ok runs (all "
                                         f"with sensitivities)")
    return math.nan, "no run finished"


def _result_cost(res: MPMResult) -> tuple[float, float, float]:
    """(solver time, per-run time, compile time) of one result, in seconds: from its runs, or
    for a result without them from its statistics' attributes (per-run time then the mean)."""
    times = run_times(res)
    if times is not None:
        return times.solver_time, times.per_run, times.compile_time
    runs, _, wall = res.cost()
    compile_ = float(res.stats.attrs[SOLVER_COMPILE_TIME]) \
        if res.stats is not None and SOLVER_COMPILE_TIME in res.stats.attrs else math.nan
    solver = wall - compile_ if np.isfinite(compile_) else wall
    return solver, (solver / runs if runs else math.nan), compile_


def cost_table(results: list[MPMResult]) -> str:
    """The seed's Tables 3/9 layout: runs, failures, solver time, per-run time, speed-up, and
    numba's compile time on a line of its own. Every time in the table is a run time (wall
    time less compile time): the header's per-run time and the rows' use one definition."""
    per_run, how = _per_run_baseline(results)
    mc_time = MC_SAMPLES_COMPARED * per_run
    lines = [f"Cost, beside the timings of seed 000's Tables 3 and 9 ({SEED_LINE}). "
             f"A run's time is its wall time less numba's "
             f"compile time. Our per-run time {seconds(per_run)} ({how}); a "
             f"{MC_SAMPLES_COMPARED:,}-sample Monte Carlo at our per-run time = "
             f"{MC_SAMPLES_COMPARED:,} × {seconds(per_run)} = {seconds(mc_time)}; speed-up "
             f"= that / the result's solver time (the sum of its run times); per run = the "
             f"same median over the result's own runs"]
    rows, compiled, unrecorded = [], [], []
    for res in results:
        runs, failed, _ = res.cost()
        solver, per, compile_ = _result_cost(res)
        speedup = mc_time / solver if np.isfinite(solver) and solver > 0 else math.nan
        rows.append([res.file, res.label, res.cv_text, f"{runs}", f"{failed}",
                     seconds(solver), seconds(per),
                     f"{speedup:,.0f}" if np.isfinite(speedup) else "?"])
        if np.isfinite(compile_):
            compiled.append(f"{res.file} {seconds(compile_)}")
        else:
            unrecorded.append(res.file)
    kinds = {input_family(r.parameters) for r in results}
    shown = [c for key, c in seed_costs().items() if key in kinds] \
        or list(seed_costs().values())
    for cost in shown:
        rows.append([f"seed {cost.example} ({cost.table})", "SMPM", f"{cost.cv:g}", "1", "-",
                     seconds(cost.smpm_seconds), "-", f"{cost.speedup:,.0f}"])
        rows.append([f"seed {cost.example} ({cost.table})", "Monte Carlo", f"{cost.cv:g}",
                     f"{cost.mc_samples:,}", "-", seconds(cost.mc_seconds),
                     seconds(cost.per_run_seconds), "1"])
    lines += grid(["result", "method", "C.V.", "runs", "failed", "solver time", "per run",
                   f"speed-up vs {MC_SAMPLES_COMPARED:,} MC"], rows, {3, 4, 5, 6, 7})
    if compiled:
        lines.append("numba compile time (the first runs of each process; left out of every "
                     "time above): " + ", ".join(compiled))
    if unrecorded:
        lines.append(f"no compile time recorded in {', '.join(unrecorded)} (a result written "
                     f"before it was): its times are wall times and include numba's compiling")
    return "\n".join(lines)


# ------------------------------------------------------------------------------ figures

def _draw_one(results, groups, refs, out, j, probe):
    div, unit, unit2 = _scale(output_units(results, out))
    fig, axes = new_figure(11.0, 3.6 * len(groups), len(groups), 2, squeeze=False,
                           sharex=True)
    t_us = results[0].times * 1e6
    words, where = output_words(results, out), probe_label(results, j)
    colors = ["#1f4e79", "#c0392b", "#2e8b57", "#8e44ad", "#d35400", "#7f8c8d", "#16a085"]
    for row, (group, ref) in enumerate(zip(groups, refs)):
        ax_mean, ax_var = axes[row]
        if ref is not None:
            mean = np.asarray(ref.statistic(out, STATISTIC_MEAN).isel(probe=j).values, float) / div
            se = mean_error(ref, out)
            if se is not None:
                s = np.asarray(se.isel(probe=j).values, float) / div
                ax_mean.fill_between(t_us, mean - BAND_WIDTH * s, mean + BAND_WIDTH * s,
                                     color="0.8", label=f"reference ± {BAND_WIDTH:g} standard "
                                                        f"errors of its mean")
            var = np.asarray(ref.statistic(out, STATISTIC_VARIANCE).isel(probe=j).values,
                             float) / div ** 2
            err, _ = variance_error(ref, out)
            if err is not None:
                e = np.asarray(err.isel(probe=j).values, float) / div ** 2
                ax_var.fill_between(t_us, var - BAND_WIDTH * e, var + BAND_WIDTH * e,
                                    color="0.8", label=f"reference ± {BAND_WIDTH:g} standard "
                                                       f"errors of its variance")
        for n, res in enumerate(r for r in group if r.stats is not None):
            style = dict(color=colors[n % len(colors)], lw=1.8 if res is ref else 1.1,
                         ls="-" if res is ref else ("--", ":", "-.")[n % 3])
            label = f"{res.words} ({res.file})" + (", reference" if res is ref else "")
            for ax, stat, d in ((ax_mean, STATISTIC_MEAN, div),
                                (ax_var, STATISTIC_VARIANCE, div ** 2)):
                values = res.statistic(out, stat)
                if values is not None:
                    ax.plot(t_us, np.asarray(values.isel(probe=j).values, float) / d,
                            label=label, **style)
        ax_mean.set_ylabel(f"mean {words} [{unit}]")
        ax_var.set_ylabel(f"variance of {words} [{unit2}]")
        for ax, what in ((ax_mean, "mean"), (ax_var, "variance")):
            ax.set_title(f"{what}, input C.V. {group[0].cv_text}", fontsize="medium")
            ax.grid(alpha=0.3)
        ax_mean.legend(fontsize="small", loc="best")
    for ax in axes[-1]:
        ax.set_xlabel("time [µs]")
    fig.suptitle(f"{words} at {where}: mean and variance over time, by method")
    return fig


def draw_figures(results: list[MPMResult], outputs: list[str], folder: Path,
                 time: float | None = None, reference: str | None = None) -> list[Path]:
    """``mpm_<output>_<probe>.png`` for every common output and probe, into ``folder``; the
    reference of each C.V. is the one of the tables (chosen at the same time)."""
    # a result without moments (FORM, SORM) has no curve to draw
    with_stats = [r for r in results if r.stats is not None and any(
        r.statistic(out, STATISTIC_MEAN) is not None for out in outputs)]
    if not with_stats:
        return []
    groups = [[r for r in g if r.stats is not None] for g in _groups(with_stats)]
    k, _ = table_time(results, time)
    refs = [choose_reference(g, outputs, k, reference) for g in groups]
    written = []
    for out in outputs:
        for j, probe in enumerate(results[0].probes):
            path = figure_path(Path(folder), "mpm", out, probe)
            name = path.name
            try:
                fig = _draw_one(with_stats, groups, refs, out, j, probe)
            except Exception as exc:  # one broken figure must not cost the others
                warnings.warn(f"figure {name} not written: {type(exc).__name__}: {exc}",
                              FigureWarning, stacklevel=2)
                continue
            path.parent.mkdir(parents=True, exist_ok=True)
            written.append(save_figure(fig, path, dpi=100))
    return written


# ------------------------------------------------------------------------------ the hook

def report(trees, folder, figures: bool = True, time: float | None = None,
           reference: str | None = None) -> tuple[str, list[Path]]:
    """The report of a set of MPM results of one scene: the text (each result's probe
    statistics against the reference in the layout of seed 000's Tables 6-8, the cost in
    that of Tables 3/9) and the PNG figures written into ``folder``: the scene map
    (``scene_map.png``) and the mean and variance of every output at every probe (none with
    ``figures=False``).

    ``time`` (seconds): the output time of Tables 6-8 (nearest output time; default the last).
    ``reference``: the file or study name of the reference result (default: the rule of
    ``choose_reference``). ``uqflow report`` uses the defaults."""
    trees = list(trees)
    if not trees:
        return "", []
    maps, map_notes = scene_map(trees[0], Path(folder)) if figures else ([], [])
    results, outputs, notes = load_results(trees)
    notes += map_notes
    parts = ["MPM comparison: each result's probe statistics against the reference, and the "
             "cost"]
    for res in results:
        if not str(res.attrs.get(STUDY_TEXT) or "").strip():
            why = str(res.attrs.get(STUDY_TEXT_OMITTED) or "").split(";")[0] \
                or "the result stores no study text"
            notes.append(f"{res.file}: {why}; its scene is identified by {res.scene[0]}")
        runs, failed, _ = res.cost()
        if res.stats is None:
            notes.append(f"{res.file}: no statistics (the study did not finish): "
                         f"{runs} runs done, {failed} failed; in the cost table only")
        elif failed:
            notes.append(f"{res.file}: {failed} of {runs} runs failed; its statistics are "
                         f"over the others")
    if outputs:
        parts.append(moments_tables(results, outputs, time, reference))
        notes += _reference_notes(results, outputs)
    parts.append(cost_table(results))
    text = "\n\n".join(parts)
    if notes:
        text += "\n\n" + "\n".join(f"note: {n}" for n in notes)
    pngs = draw_figures(results, outputs, Path(folder), time, reference) \
        if figures and outputs else []
    return text, maps + pngs


# ------------------------------------------------------------------------------ command line

def main(argv: list[str] | None = None) -> int:
    """``python -m solvers.mpm.report RESULT... [--time S] [--reference NAME] [--figures DIR |
    --no-figures]``: the comparison alone, with the two choices ``uqflow report`` leaves to
    their defaults. Exit 2 with one line on a refused set of results."""
    import argparse
    import sys

    from uqflow.report import open_result

    parser = argparse.ArgumentParser(prog="python -m solvers.mpm.report",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("results", type=Path, nargs="+")
    parser.add_argument("--time", type=float, default=None,
                        help="output time of Tables 6-8 in seconds (nearest output time; "
                             "default: the last)")
    parser.add_argument("--reference", default=None,
                        help="file or study name of the reference (default: the Monte Carlo "
                             "result with the smallest relative standard error)")
    parser.add_argument("--figures", type=Path, default=None,
                        help="folder for the PNGs (default: beside the first result)")
    parser.add_argument("--no-figures", action="store_true")
    args = parser.parse_args(argv)
    try:
        trees = [open_result(p) for p in args.results]
        folder = args.figures or args.results[0].resolve().parent
        text, pngs = report(trees, folder, figures=not args.no_figures, time=args.time,
                            reference=args.reference)
    except StudyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(text)
    for png in pngs:
        print(f"figure: {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
