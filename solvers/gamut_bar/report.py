"""What gamut-bar results add to ``uqflow report``: seed 002's Table 1 and Figs. 21-32.

``report(trees, folder, figures=True) -> (text, pngs)`` takes any subset of gamut-bar results
(the 20 studies in ``studies/gamut_bar`` or others) and

- prints seed 002's Table 1 layout (rows M1 n', M1 K', M2 n', M2 K', and M2 with n_ro = 21
  when such results are given; columns stochastic grid / uniform grid / deterministic /
  experimental) with our mean n' and K' beside the seed's numbers and the relative
  difference; the spread of n' and K' over the realizations; the failure strains; and the
  mean monotonic curve against the deterministic one at ``STRAINS``;
- draws, into ``folder``, the seed's figures that the given results allow: monotonic curves
  of the realizations with their mean, the deterministic curve and Ramberg-Osgood (Figs.
  21-24); the hysteresis loops of one realization (Figs. 25-26); its log-log fit of the
  stress amplitude against the plastic strain amplitude (Figs. 27-28); n' and K' per
  realization with their mean and the deterministic value (Figs. 29-32).

A result is identified by its root attributes: ``method`` (``nominal``: deterministic, any
other: stochastic) and the scene it ran (``uqflow.report.scene_ran``: the stored study text's
or its unchanged scene file's, with the recorded ``--set`` overrides): material, property
overrides such as ``n_ro``, ``grid`` and ``loading``. The seed's numbers come from
``data/seed_tables.toml`` (a copy of ``tests/data/seed_tables.toml``), never retyped here.

``mean_curve(runs, strains)`` interpolates every ok realization's (strain, stress) path at
the given strains; a realization that failed before a strain does not count there.
``comparison_tables(trees)`` returns the tables as ``Table`` objects (text or markdown), for
``benchmarks/gamut_bar_table1.py``.
"""

from __future__ import annotations

import math
import re
import tomllib
import warnings
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import xarray as xr

from solvers.gamut_bar.bar_figure import draw as draw_bar, field_realizations
from solvers.gamut_bar.materials import MATERIALS
from uqflow.report import FigureWarning, figure_path, new_figure, save_figure, scene_ran

__all__ = ["report", "mean_curve", "comparison_tables", "identify", "seed_tables",
           "GamutResult", "Table", "STRAINS"]

#: What "seed 002" is, said once wherever its Table 1 or figures are compared.
SEED_LINE = ("seed 002: the stochastic nonlocal deformation-gamut bar, the published study "
             "these results are compared with")

#: Strains at which the mean monotonic curve is compared with the deterministic one.
STRAINS = (0.005, 0.02, 0.05, 0.1)

#: Scene keys that change the material (a result with any of them is its own case).
PROPERTY_KEYS = ("E", "sigma_y", "sigma_f", "eps_f", "n_ro", "K_ro", "rho", "nu", "R", "area",
                 "length")
SCENE_DEFAULTS = {"material": "M1", "grid": "uniform", "loading": "monotonic"}
GRIDS = ("stochastic", "uniform")          # Table 1's column order
SEED_KEYS = {"M1": "table1_material1", "M2": "table1_material2"}


# ------------------------------------------------------------------------------ seed numbers

def seed_tables() -> dict:
    """The ``[gamut_bar]`` table of the seed numbers (package data ``data/seed_tables.toml``,
    an exact copy of ``tests/data/seed_tables.toml``)."""
    text = (resources.files("solvers.gamut_bar") / "data" / "seed_tables.toml").read_text(
        encoding="utf-8")
    return tomllib.loads(text)["gamut_bar"]


def material_properties(material: str, overrides: dict | None = None) -> dict:
    """E, sigma_y, n_ro, K_ro, eps_f, ... of a material, with the scene's overrides."""
    props = dict(MATERIALS[material])
    props.update({k: float(v) for k, v in (overrides or {}).items()})
    return props


def ro_curve(props: dict, points: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """Ramberg-Osgood ε = σ/E + K_ro (σ/σ_y)^n_ro from 0 to the stress at ε_f (parametric in σ,
    no inversion)."""
    E, sy, n, K = props["E"], props["sigma_y"], props["n_ro"], props["K_ro"]
    eps_f = props["eps_f"]
    lo, hi = 0.0, min(E * eps_f, sy * (eps_f / K) ** (1.0 / n))
    for _ in range(200):  # σ at ε_f, by bisection
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if mid / E + K * (mid / sy) ** n > eps_f else (mid, hi)
    # denser near the knee: uniform in σ^2 would waste points in the elastic part
    sigma = hi * np.sqrt(np.linspace(0.0, 1.0, points))
    return sigma / E + K * (sigma / sy) ** n, sigma


def ro_stress_at(props: dict, strains) -> np.ndarray:
    eps, sig = ro_curve(props, 4000)
    return np.interp(np.asarray(strains, float), eps, sig, right=np.nan)


# ------------------------------------------------------------------------------ identifying

@dataclass
class GamutResult:
    """One gamut-bar result file, identified."""

    tree: xr.DataTree
    name: str
    method: str
    material: str
    overrides: dict
    grid: str
    loading: str
    runs: xr.Dataset
    ok: np.ndarray = field(repr=False)
    source: str = "study"       # where the case was read: "study", "description" or ""
    scene: dict = field(default_factory=dict)          # as the study wrote it
    field_tables: list = field(default_factory=list)   # the study's [[fields]]

    @property
    def stochastic(self) -> bool:
        return self.method != "nominal"

    @property
    def case(self) -> str:
        """"M1", "M2 (n_ro = 21)"."""
        if not self.overrides:
            return self.material
        return self.material + " (" + ", ".join(f"{k} = {v:g}" for k, v in
                                                sorted(self.overrides.items())) + ")"

    @property
    def slug(self) -> str:
        parts = [self.material.lower()] + [re.sub(r"[^A-Za-z0-9]", "", f"{k}{v:g}").lower()
                                           for k, v in sorted(self.overrides.items())]
        return "_".join(parts)

    @property
    def total(self) -> int:
        return int(self.ok.size)

    @property
    def n_ok(self) -> int:
        return int(self.ok.sum())

    def values(self, name: str) -> np.ndarray | None:
        """The output ``name`` of the ok realizations (realization first), None if absent."""
        if name not in self.runs:
            return None
        return np.asarray(self.runs[name].values, dtype=float)[self.ok]

    def describe(self) -> str:
        return f"{self.case}, {self.grid} grid, {self.loading}"

    def order(self) -> tuple:
        return (self.material, sorted(self.overrides.items()), self.loading != "monotonic",
                GRIDS.index(self.grid) if self.grid in GRIDS else 9, self.stochastic)


def _study_of(attrs: dict) -> dict:
    """The stored study text, parsed ({} if there is none or it is not TOML)."""
    try:
        return tomllib.loads(str(attrs.get("study") or ""))
    except (tomllib.TOMLDecodeError, ValueError):
        return {}


def _scene_of(attrs: dict) -> tuple[dict, str]:
    """The scene the result ran (``uqflow.report.scene_ran``: the stored study text's scene,
    or the scene file it read while unchanged, with the recorded ``--set`` overrides) and
    where it came from: "study" or, as the last resort, "description" (the solver's
    description names material, loading and grid, not property overrides); ({}, "") when
    neither tells."""
    scene, _ = scene_ran(attrs)
    if scene is not None:
        return scene, "study"
    # "gamut_bar/M1 monotonic, 500 local bonds, uniform grid"
    m = re.search(r"gamut_bar/(\w+) (\w+), \d+ local bonds, (\w+) grid",
                  str(attrs.get("solver_description", "")))
    if m:
        return {"material": m[1], "loading": m[2], "grid": m[3]}, "description"
    return {}, ""


def _without_study_text(attrs: dict) -> str:
    """Why a result's scene is not read from its study text (one clause)."""
    if str(attrs.get("study") or "").strip():
        return scene_ran(attrs)[1]
    return str(attrs.get("study_text_omitted") or "").split(";")[0] \
        or "the result stores no study text"


def identify(tree: xr.DataTree) -> GamutResult | None:
    """The result's case (material, overrides), grid, loading and method; None if it is not
    a gamut-bar result with runs."""
    attrs = dict(tree.attrs)
    if str(attrs.get("solver", "")) != "gamut_bar" or "runs" not in tree.children:
        return None
    found, source = _scene_of(attrs)
    scene = dict(SCENE_DEFAULTS, **found)
    runs = tree["runs"].to_dataset()
    if "status" in runs:
        ok = np.asarray(runs["status"].values).astype(str) == "ok"
    else:
        ok = np.ones(runs.sizes.get("realization", 1), bool)
    method = str(attrs.get("method") or (tree["statistics"].attrs.get("method", "")
                                         if "statistics" in tree.children else ""))
    overrides = {k: float(scene[k]) for k in PROPERTY_KEYS if k in scene}
    tables = _study_of(attrs).get("fields", [])
    return GamutResult(tree=tree, name=str(attrs.get("study_name", "?")), method=method,
                       material=str(scene["material"]), overrides=overrides,
                       grid=str(scene["grid"]), loading=str(scene["loading"]), runs=runs,
                       ok=ok, source=source, scene=found,
                       field_tables=tables if isinstance(tables, list) else [])


# ------------------------------------------------------------------------------ mean curve

def stress_at(strain, stress, targets) -> np.ndarray:
    """Stress of one (strain, stress) path at each target strain: linear between the two
    states where the path first reaches the target; NaN where it never does (the bar failed
    before)."""
    e = np.asarray(strain, float).ravel()
    s = np.asarray(stress, float).ravel()
    keep = np.isfinite(e) & np.isfinite(s)
    e, s = e[keep], s[keep]
    t = np.atleast_1d(np.asarray(targets, float))
    out = np.full(t.shape, np.nan)
    if e.size == 0:
        return out
    reached = e[None, :] >= t[:, None]
    has = reached.any(axis=1)
    j = np.argmax(reached, axis=1)
    for k in np.flatnonzero(has):
        i = j[k]
        if i == 0:
            out[k] = s[0] if e[0] == t[k] else np.nan
            continue
        e0, e1, s0, s1 = e[i - 1], e[i], s[i - 1], s[i]
        out[k] = s1 if e1 == e0 else s0 + (t[k] - e0) * (s1 - s0) / (e1 - e0)
    return out


def mean_curve(runs: xr.Dataset, strains) -> tuple[np.ndarray, np.ndarray]:
    """Mean stress of the ok realizations' paths at ``strains`` and how many count at each.

    ``runs``: a dataset with ``strain`` and ``stress`` (realization, step) — the ``runs`` group
    of a result — and optionally ``status`` (only ``"ok"`` realizations are used); a single
    run without the realization dimension works too. Every path is interpolated linearly at
    each strain; a realization whose path ends before a strain (it failed earlier) does not
    count there. Where none counts the mean is NaN.
    """
    e = np.asarray(runs["strain"].values, float)
    s = np.asarray(runs["stress"].values, float)
    if e.ndim == 1:
        e, s = e[None], s[None]
    if "status" in runs and "realization" in runs["status"].dims:
        ok = np.asarray(runs["status"].values).astype(str).ravel() == "ok"
        e, s = e[ok], s[ok]
    t = np.atleast_1d(np.asarray(strains, float))
    vals = np.array([stress_at(e[r], s[r], t) for r in range(e.shape[0])]).reshape(-1, t.size)
    count = np.isfinite(vals).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, np.nansum(np.nan_to_num(vals, nan=0.0), axis=0)
                        / np.maximum(count, 1), np.nan)
    return mean, count


# ------------------------------------------------------------------------------ tables

@dataclass
class Table:
    title: str
    header: list[str]
    rows: list[list[str]]
    notes: list[str] = field(default_factory=list)

    def _right(self) -> set[int]:
        """Columns of numbers (right-aligned)."""
        return {i for i in range(1, len(self.header))
                if all(_numeric(r[i]) or r[i] in ("–", "") for r in self.rows)}

    def text(self) -> str:
        widths = [max(len(r[i]) for r in [self.header, *self.rows])
                  for i in range(len(self.header))]
        right = self._right()

        def line(cells):
            return "  ".join(c.rjust(w) if i in right else c.ljust(w)
                             for i, (c, w) in enumerate(zip(cells, widths))).rstrip()

        lines = [self.title, "", line(self.header), "  ".join("-" * w for w in widths),
                 *map(line, self.rows)]
        return "\n".join(lines + ([""] + self.notes if self.notes else []))

    def markdown(self) -> str:
        def esc(c):
            return c.replace("|", "\\|")

        right = self._right()
        lines = ["| " + " | ".join(map(esc, self.header)) + " |",
                 "|" + "|".join("---:" if i in right else "---"
                                for i in range(len(self.header))) + "|"]
        lines += ["| " + " | ".join(map(esc, r)) + " |" for r in self.rows]
        notes = [f"- {n}" for n in self.notes]
        return "\n".join([f"**{self.title}**", "", *lines] + ([""] + notes if notes else []))


def _numeric(cell: str) -> bool:
    return bool(re.fullmatch(r"[-+]?[\d.]+(e[-+]?\d+)?( %)?", cell.strip()))


def _g(x, digits=4) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{x:.{digits}g}"


def _mpa(x, digits=1) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{x / 1e6:.{digits}f}"


def _rel(ours, ref) -> str:
    """ours/ref - 1 in percent; "" when either is missing or not finite, or ref is 0 (a
    deterministic bar that failed before the strain has no stress there)."""
    if ours is None or ref is None or not np.isfinite(ours) or not np.isfinite(ref) or not ref:
        return ""
    return f"{100.0 * (ours / ref - 1.0):+.1f} %"


def _seed_text(value, quantity) -> str:
    """A seed number as the seed prints it (K' in MPa)."""
    if isinstance(value, (list, tuple)):
        return "–".join(_seed_text(v, quantity) for v in value)
    return f"{value:.10g}" if quantity == "n" else f"{value / 1e6:.10g}"


def _ok_mean(res: GamutResult | None, name: str) -> float | None:
    if res is None:
        return None
    v = res.values(name)
    if v is None:
        return None
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else None


class _Index:
    """The results grouped by (case, loading, grid, stochastic); the first of duplicates."""

    def __init__(self, results: list[GamutResult]):
        self.results = sorted(results, key=GamutResult.order)
        self.by_key: dict = {}
        self.duplicates: list[GamutResult] = []
        for r in self.results:
            key = (r.case, r.loading, r.grid, r.stochastic)
            if key in self.by_key:
                self.duplicates.append(r)
            else:
                self.by_key[key] = r

    def get(self, case, loading, grid, stochastic) -> GamutResult | None:
        return self.by_key.get((case, loading, grid, stochastic))

    def deterministic_for(self, case, loading, grid) -> tuple[GamutResult | None, str]:
        """The deterministic result on the same grid, else on the other one (and its grid)."""
        for g in (grid, *[x for x in GRIDS if x != grid]):
            r = self.get(case, loading, g, False)
            if r is not None:
                return r, g
        return None, ""

    def cases(self, loading=None) -> list[tuple[str, GamutResult]]:
        seen = {}
        for r in self.results:
            if loading is None or r.loading == loading:
                seen.setdefault(r.case, r)
        return list(seen.items())

    def groups(self, loading) -> list[tuple[str, str]]:
        """(case, grid) pairs with any result of this loading, in order."""
        out = []
        for r in self.results:
            if r.loading == loading and (r.case, r.grid) not in out:
                out.append((r.case, r.grid))
        return out


def _results_table(idx: _Index) -> Table:
    rows = []
    for r in idx.results:
        complete = int(r.tree.attrs.get("complete", 1)) and "statistics" in r.tree.children
        rows.append([r.name, r.case, r.grid, r.loading,
                     "stochastic" if r.stochastic else "deterministic", r.method,
                     f"{r.n_ok}/{r.total}" + ("" if complete else " (unfinished)")])
    notes = [f"ignored (same case, grid, loading and method as an earlier one): {r.name}"
             for r in idx.duplicates]
    notes += [f"{r.name}: {_without_study_text(dict(r.tree.attrs))}; its case is read from the "
              f"solver's description, which names no property override (such as n_ro)"
              for r in idx.results if r.source == "description"]
    return Table("gamut_bar results", ["study", "case", "grid", "loading", "kind", "method",
                                       "ok runs"], rows, notes)


def _table1(idx: _Index, seed: dict) -> Table | None:
    if not any(r.loading == "cyclic" for r in idx.results):
        return None
    cases = ["M1", "M2"] + [c for c, r in idx.cases("cyclic") if c not in ("M1", "M2")]
    material = {c: r.material for c, r in idx.cases()}
    det_stoch = any(idx.get(c, "cyclic", "stochastic", False) is not None for c in cases)
    header = ["", "stochastic grid", "uniform grid", "deterministic"] \
        + (["deterministic, stochastic grid"] if det_stoch else []) + ["experimental"]
    rows, notes = [], []
    for case in cases:
        mat = material.get(case, case)
        ref = seed.get(SEED_KEYS.get(mat, ""), {})
        for q, out in (("n", "n_prime"), ("K", "K_prime")):
            label = f"{case} n'" if q == "n" else f"{case} K' [MPa]"
            k = 0 if q == "n" else 1
            fmt = (lambda v: _g(v, 4)) if q == "n" else (lambda v: _mpa(v, 1))
            row = [label]
            columns = [(idx.get(case, "cyclic", "stochastic", True), "stochastic_grid"),
                       (idx.get(case, "cyclic", "uniform", True), "uniform_grid"),
                       (idx.get(case, "cyclic", "uniform", False), "deterministic")]
            if det_stoch:
                columns.append((idx.get(case, "cyclic", "stochastic", False), None))
            for res, key in columns:
                ours = _ok_mean(res, out)
                seed_value = ref.get(key, [None, None])[k] if key else None
                text = fmt(ours)
                if seed_value is not None:
                    text += f" / {_seed_text(seed_value, q)}"
                    diff = _rel(ours, seed_value)
                    text += f" ({diff})" if diff else ""
                row.append(text)
            if "experimental" in ref:
                exp = ref["experimental"][k]
            else:
                exp = ref.get("experimental_n") if q == "n" else ref.get("experimental_K_range")
            row.append(_seed_text(exp, q) if exp is not None else "–")
            rows.append(row)
        if case not in ("M1", "M2") and mat in SEED_KEYS:
            notes.append(f"{case}: the seed's numbers are those of {mat} (seed 002 prints only "
                         f"one {mat}; its n' = 0.04762 is 1/21)" if "n_ro" in case else
                         f"{case}: the seed's numbers are those of {mat}")
    for case in cases:
        for grid in GRIDS:
            r = idx.get(case, "cyclic", grid, True)
            if r is not None and r.n_ok < r.total:
                notes.append(f"{case}, {grid} grid: means over the {r.n_ok} of {r.total} "
                             f"realizations that finished")
    notes.insert(0, "each cell: ours / seed 002 (ours/seed - 1); ours = mean over the ok "
                    "realizations of n' and K' (fitted to each one's loops); deterministic = the "
                    "nominal run on the uniform grid; experimental: the seed's column only; "
                    "'–': no such result given")
    return Table("Table 1 (seed 002): mean cyclic strain hardening exponent n' and cyclic "
                 "strength coefficient K'", header, rows, notes)


def _spread_table(idx: _Index) -> Table | None:
    rows = []
    for r in idx.results:
        if r.loading != "cyclic" or not r.stochastic:
            continue
        n, K = r.values("n_prime"), r.values("K_prime")
        if n is None or K is None:
            continue
        n, K = n[np.isfinite(n)], K[np.isfinite(K)]
        if not n.size:
            rows.append([r.case, r.grid, f"{r.n_ok}/{r.total}", "–", "–", "–", "–"])
            continue
        rows.append([r.case, r.grid, f"{r.n_ok}/{r.total}",
                     f"{n.mean():.4g} ± {n.std(ddof=1) if n.size > 1 else 0:.2g}",
                     f"{n.min():.4g} .. {n.max():.4g}",
                     f"{K.mean() / 1e6:.1f} ± {(K.std(ddof=1) if K.size > 1 else 0) / 1e6:.2g}",
                     f"{K.min() / 1e6:.1f} .. {K.max() / 1e6:.1f}"])
    if not rows:
        return None
    return Table("n' and K' over the realizations (seed 002, Figs. 29-32)",
                 ["case", "grid", "ok runs", "n' mean ± std", "n' min .. max",
                  "K' [MPa] mean ± std", "K' [MPa] min .. max"], rows)


def _failure_table(idx: _Index) -> Table | None:
    rows = []
    for case, _ in idx.cases():
        for loading in ("monotonic", "cyclic"):
            for grid in GRIDS:
                sto = idx.get(case, loading, grid, True)
                det, det_grid = idx.deterministic_for(case, loading, grid)
                if sto is None and (det is None or det_grid != grid):
                    continue
                fs = sto.values("failure_strain") if sto is not None else None
                fs = fs[np.isfinite(fs)] if fs is not None else np.array([])
                ss = sto.values("failure_stress") if sto is not None else None
                ss = ss[np.isfinite(ss)] if ss is not None else np.array([])
                d_e = _ok_mean(det, "failure_strain")
                d_s = _ok_mean(det, "failure_stress")
                mean_e = float(fs.mean()) if fs.size else None
                det_text = _g(d_e, 4) + ("" if det_grid in ("", grid) else
                                         f" ({det_grid} grid)")
                rows.append([case, loading, grid,
                             f"{sto.n_ok}/{sto.total}" if sto is not None else "–",
                             _g(mean_e, 4),
                             f"{fs.min():.4g} .. {fs.max():.4g}" if fs.size else "–",
                             det_text,
                             f"{mean_e / d_e:.3f}" if mean_e and d_e else "–",
                             _mpa(float(ss.mean()) if ss.size else None), _mpa(d_s)])
    if not rows:
        return None
    props = {case: material_properties(r.material, r.overrides) for case, r in idx.cases()}
    eps_f = ", ".join(f"{c} {p['eps_f']:g}" for c, p in props.items())
    header = ["case", "loading", "grid", "ok runs", "mean failure strain", "min .. max",
              "deterministic", "mean/det.", "mean failure stress [MPa]", "det. [MPa]"]
    notes = [f"material failure strain eps_f: {eps_f}"]
    if not any(not r.stochastic for r in idx.results):
        header, rows = _without(header, rows, DETERMINISTIC_FAILURE_COLUMNS)
        notes.append(NO_DETERMINISTIC_NOTE)
    return Table("Failure: bar strain and stress at failure (cyclic: where the bar broke, in "
                 "the cycles or in the pull after them)", header, rows, notes)


#: Columns of the curve and failure tables that need a deterministic result, left out when
#: none is given (a study of random fields alone has no deterministic counterpart).
DETERMINISTIC_CURVE_COLUMNS = ("deterministic [MPa]", "mean/det. - 1")
DETERMINISTIC_FAILURE_COLUMNS = ("deterministic", "mean/det.", "det. [MPa]")
NO_DETERMINISTIC_NOTE = ("no deterministic result given (the same scene with method "
                         "\"nominal\"): the columns against the deterministic bar are left out")


def _without(header: list[str], rows: list[list[str]], drop) -> tuple[list, list]:
    keep = [i for i, name in enumerate(header) if name not in drop]
    return [header[i] for i in keep], [[row[i] for i in keep] for row in rows]


def _with_path(res: GamutResult | None) -> GamutResult | None:
    """``res`` if its runs hold the stress-strain paths, else None."""
    return res if res is not None and {"strain", "stress"} <= set(res.runs) else None


def _curve_table(idx: _Index, strains) -> Table | None:
    rows = []
    for case, grid in idx.groups("monotonic"):
        # a study may store scalars alone (failure_strain for a limit state): no path, no curve
        sto = _with_path(idx.get(case, "monotonic", grid, True))
        det, det_grid = idx.deterministic_for(case, "monotonic", grid)
        det = _with_path(det)
        if sto is None and det is None:
            continue
        any_r = sto or det
        props = material_properties(any_r.material, any_r.overrides)
        ro = ro_stress_at(props, strains)
        if sto is not None:
            mean, count = mean_curve(sto.runs, strains)
        else:
            mean, count = np.full(len(strains), np.nan), np.zeros(len(strains), int)
        if det is not None:
            dval, _ = mean_curve(det.runs, strains)
        else:
            dval = np.full(len(strains), np.nan)
        for k, eps in enumerate(strains):
            rows.append([case, grid, f"{eps:g}", _mpa(mean[k]),
                         f"{count[k]} of {sto.n_ok}" if sto is not None else "–",
                         _mpa(dval[k]) + ("" if det_grid in ("", grid) else
                                          f" ({det_grid} grid)"),
                         _rel(mean[k], dval[k]) or "–", _mpa(ro[k]),
                         _rel(mean[k], ro[k]) or "–"])
    if not rows:
        return None
    header = ["case", "grid", "strain", "mean stress [MPa]", "realizations counted",
              "deterministic [MPa]", "mean/det. - 1", "Ramberg-Osgood [MPa]", "mean/RO - 1"]
    notes = ["mean over the ok realizations whose path reaches the strain (a realization that "
             "failed before a strain does not count there); paths interpolated linearly; '–' "
             "where none (or the deterministic bar) reaches it, or no deterministic result of "
             "the case is given"]
    with_deterministic = any(_with_path(idx.deterministic_for(case, "monotonic", grid)[0])
                             is not None for case, grid in idx.groups("monotonic"))
    title = ("Monotonic curves (seed 002, Figs. 21-24): mean stress of the realizations against "
             + ("the deterministic bar and " if with_deterministic else "") + "Ramberg-Osgood")
    if not with_deterministic:
        header, rows = _without(header, rows, DETERMINISTIC_CURVE_COLUMNS)
        notes.append(NO_DETERMINISTIC_NOTE)
    return Table(title, header, rows, notes)


def _tables(results: list[GamutResult], strains=STRAINS) -> list[Table]:
    idx = _Index(results)
    seed = seed_tables()
    tables = [_results_table(idx), _table1(idx, seed), _spread_table(idx),
              _failure_table(idx), _curve_table(idx, strains)]
    return [t for t in tables if t is not None]


def comparison_tables(trees, strains=STRAINS) -> list[Table]:
    """The report's tables (results, Table 1, spread, failure, mean curves) as ``Table``s."""
    results = [r for r in map(identify, trees) if r is not None and r.source]
    return _tables(results, strains) if results else []


# ------------------------------------------------------------------------------ figures

def _figure(width=6.4, height=4.4, ncols=1, nrows=1, **kwargs):
    fig, axes = new_figure(width, height, nrows, ncols, squeeze=False, **kwargs)
    return fig, axes


def _realization_label(res: GamutResult, i: int) -> str:
    if not res.stochastic:
        return "deterministic run"
    real = res.runs["realization"].values if "realization" in res.runs.coords else None
    number = int(real[i]) + 1 if real is not None else i + 1
    return f"realization {number}"


def _last_ok(res: GamutResult) -> int | None:
    ok = np.flatnonzero(res.ok)
    return int(ok[-1]) if ok.size else None


def _path(res: GamutResult, i: int) -> tuple[np.ndarray, np.ndarray]:
    e = np.asarray(res.runs["strain"].values, float).reshape(res.total, -1)[i]
    s = np.asarray(res.runs["stress"].values, float).reshape(res.total, -1)[i]
    keep = np.isfinite(e) & np.isfinite(s)
    return e[keep], s[keep]


def _fig_monotonic(idx: _Index, case: str, grid: str):
    sto = idx.get(case, "monotonic", grid, True)
    det, det_grid = idx.deterministic_for(case, "monotonic", grid)
    if (sto is None and det is None) or ("strain" not in (sto or det).runs):
        return None
    ref = sto or det
    props = material_properties(ref.material, ref.overrides)
    ro_e, ro_s = ro_curve(props)
    fig, axes = _figure(12.0, 4.8, ncols=2)
    last_failure = 0.0
    if sto is not None and sto.n_ok:
        fs = sto.values("failure_strain")
        last_failure = float(np.nanmax(fs)) if fs is not None and np.isfinite(fs).any() else 0
    for ax in axes[0]:
        if sto is not None:
            ends = []
            for n, i in enumerate(np.flatnonzero(sto.ok)):
                e, s = _path(sto, i)
                ax.plot(100 * e, s / 1e6, color="#9ab7d3", lw=0.7, alpha=0.8,
                        label=f"{sto.n_ok} realizations" if n == 0 else None)
                if e.size:
                    ends.append((e[-1], s[-1]))
            if ends:
                ends = np.asarray(ends)
                ax.plot(100 * ends[:, 0], ends[:, 1] / 1e6, "x", color="#1f4e79", ms=4, mew=0.8,
                        label="failure of a realization", zorder=5)
            if sto.n_ok:
                top = max(last_failure, 1e-9)
                grid_e = np.linspace(0.0, top, 400)
                mean, count = mean_curve(sto.runs, grid_e)
                full = count == sto.n_ok
                ax.plot(np.where(full, 100 * grid_e, np.nan), mean / 1e6, color="#1f4e79", lw=2,
                        label=f"mean (all {sto.n_ok})")
                part = (count > 0) & ~full
                if part.any():
                    # continue the line one point back so the two pieces join
                    first = int(np.argmax(part))
                    part[max(first - 1, 0)] = True
                    ax.plot(np.where(part, 100 * grid_e, np.nan), mean / 1e6, color="#1f4e79",
                            lw=1.5, ls="--", label="mean of the survivors")
        if det is not None:
            e, s = _path(det, 0) if det.n_ok else (np.array([]), np.array([]))
            ax.plot(100 * e, s / 1e6, color="k", lw=1.5,
                    label="deterministic" + ("" if det_grid == grid else f" ({det_grid} grid)"))
        ax.plot(100 * ro_e, ro_s / 1e6, color="#c0392b", lw=1.2, ls=":",
                label="Ramberg-Osgood (calibration)")
        ax.set_xlabel("strain [%]")
        ax.set_ylabel("stress [MPa]")
        ax.grid(alpha=0.3)
    axes[0][0].set_title("whole curves")
    if last_failure > 0:
        zoom = min(1.15 * last_failure, props["eps_f"] * 1.05)
        axes[0][1].set_xlim(0, 100 * zoom)
        axes[0][1].set_title(f"up to the last failure of a realization (strain "
                             f"{100 * last_failure:.3g} %)")
    else:
        axes[0][1].set_xlim(0, 10 * props["eps_f"])
        axes[0][1].set_title("first tenth of the failure strain")
    axes[0][0].legend(loc="lower right", fontsize="small")
    what = (f"{sto.n_ok} realizations, their mean" if sto is not None else "deterministic") \
        + ", deterministic and Ramberg-Osgood curves"
    fig.suptitle(f"{case}, {grid} grid, monotonic loading: {what} (seed 002, Figs. 21-24)")
    _seed_footnote(fig)
    return fig


def _seed_footnote(fig):
    fig.supxlabel(SEED_LINE, fontsize="x-small", color="0.35")


def _shown(idx: _Index, case: str, grid: str) -> GamutResult | None:
    """The cyclic result whose realization the loop figures show: the stochastic one (its
    last ok realization, as the seed shows realization 30), else the deterministic one."""
    for stochastic in (True, False):
        r = idx.get(case, "cyclic", grid, stochastic)
        if r is not None and r.n_ok:
            return r
    return None


def _fig_loops(idx: _Index, case: str, grid: str):
    res = _shown(idx, case, grid)
    if res is None or "strain" not in res.runs:
        return None
    i = _last_ok(res)
    if i is None:
        return None
    e, s = _path(res, i)
    fig, axes = _figure(7.0, 5.0)
    ax = axes[0][0]
    ax.plot(100 * e, s / 1e6, color="#1f4e79", lw=0.6)
    ax.axhline(0, color="0.5", lw=0.5)
    ax.axvline(0, color="0.5", lw=0.5)
    ax.set_xlabel("strain [%]")
    ax.set_ylabel("stress [MPa]")
    ax.grid(alpha=0.3)
    ax.set_title(f"{case}, {grid} grid, cyclic loading: hysteresis loops of "
                 f"{_realization_label(res, i)} (seed 002, Figs. 25-26)", fontsize="medium")
    _seed_footnote(fig)
    return fig


def _fig_loglog(idx: _Index, case: str, grid: str):
    res = _shown(idx, case, grid)
    if res is None or "stress_amplitude" not in res.runs \
            or "plastic_strain_amplitude" not in res.runs:
        return None
    i = _last_ok(res)
    if i is None:
        return None
    fig, axes = _figure(6.4, 4.6)
    ax = axes[0][0]

    def draw(r, j, color, label, marker):
        sa = np.asarray(r.runs["stress_amplitude"].values, float).reshape(r.total, -1)[j]
        ep = np.asarray(r.runs["plastic_strain_amplitude"].values, float).reshape(r.total,
                                                                                   -1)[j]
        use = np.isfinite(ep) & np.isfinite(sa) & (ep > 0)
        if "strain_amplitude" in r.runs:
            ea = np.asarray(r.runs["strain_amplitude"].values, float).reshape(r.total, -1)[j]
            use &= ep > 1e-6 * ea
        if not use.any():
            return
        ax.loglog(100 * ep[use], sa[use] / 1e6, marker, color=color, label=f"{label}: loops")
        if "n_prime" in r.runs and "K_prime" in r.runs:
            n = float(np.asarray(r.runs["n_prime"].values, float).ravel()[j])
            K = float(np.asarray(r.runs["K_prime"].values, float).ravel()[j])
            if np.isfinite(n) and np.isfinite(K):
                x = np.geomspace(ep[use].min(), ep[use].max(), 50)
                ax.loglog(100 * x, K * x ** n / 1e6, "-", color=color, lw=1.2,
                          label=f"{label}: fit n' = {n:.4g}, K' = {K / 1e6:.1f} MPa")

    draw(res, i, "#1f4e79", _realization_label(res, i), "o")
    if res.stochastic:
        det, det_grid = idx.deterministic_for(case, "cyclic", grid)
        if det is not None and det.n_ok:
            draw(det, 0, "0.4", "deterministic" + ("" if det_grid == grid else
                                                   f" ({det_grid} grid)"), "s")
    from matplotlib.ticker import FuncFormatter

    plain = FuncFormatter(lambda v, _: f"{v:g}")
    ax.xaxis.set_major_formatter(plain)
    ax.xaxis.set_minor_formatter(FuncFormatter(
        lambda v, _: f"{v:g}" if v > 0 and round(v / 10 ** math.floor(math.log10(v)))
        in (2, 5) else ""))
    ax.yaxis.set_major_formatter(plain)
    ax.yaxis.set_minor_formatter(plain)
    ax.set_xlabel("plastic strain amplitude [%]")
    ax.set_ylabel("stress amplitude [MPa]")
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="lower right", fontsize="small")
    ax.set_title(f"{case}, {grid} grid, cyclic loading: stress amplitude = K' × (plastic "
                 f"strain amplitude)^n'\nfitted to the loops of {_realization_label(res, i)} "
                 f"(seed 002, Figs. 27-28)", fontsize="medium")
    _seed_footnote(fig)
    return fig


def _fig_constants(idx: _Index, case: str, grid: str, seed: dict):
    sto = idx.get(case, "cyclic", grid, True)
    if sto is None or "n_prime" not in sto.runs or "K_prime" not in sto.runs or not sto.n_ok:
        return None
    det, det_grid = idx.deterministic_for(case, "cyclic", grid)
    ref = seed.get(SEED_KEYS.get(sto.material, ""), {})
    real = (sto.runs["realization"].values + 1) if "realization" in sto.runs.coords \
        else np.arange(1, sto.total + 1)
    fig, axes = _figure(7.0, 6.0, nrows=2, sharex=True)
    for ax, out, name, scale, unit, k in (
            (axes[0][0], "n_prime", "cyclic strain hardening exponent n'", 1.0, " [-]", 0),
            (axes[1][0], "K_prime", "cyclic strength coefficient K'", 1e6, " [MPa]", 1)):
        v = np.asarray(sto.runs[out].values, float).ravel()
        ok = sto.ok & np.isfinite(v)
        ax.plot(real[ok], v[ok] / scale, "o", color="#1f4e79", ms=4, label="realizations")
        mean = float(v[ok].mean()) if ok.any() else math.nan
        ax.axhline(mean / scale, color="#1f4e79", lw=1.5,
                   label=f"mean {mean / scale:.4g}")
        d = _ok_mean(det, out)
        if d is not None:
            ax.axhline(d / scale, color="k", lw=1.2, ls="--",
                       label=f"deterministic {d / scale:.4g}"
                       + ("" if det_grid == grid else f" ({det_grid} grid)"))
        key = {"stochastic": "stochastic_grid", "uniform": "uniform_grid"}.get(grid)
        if key in ref:
            sv = ref[key][k]
            ax.axhline(sv / scale, color="#c0392b", lw=1.2, ls=":",
                       label=f"seed 002, Table 1: mean {sv / scale:.6g}")
        ax.set_ylabel(name + unit)
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    from matplotlib.ticker import MaxNLocator

    axes[1][0].xaxis.set_major_locator(MaxNLocator(integer=True))
    axes[1][0].set_xlabel("realization")
    fig.suptitle(f"{case}, {grid} grid, cyclic loading: n' and K' per realization\n"
                 f"({sto.n_ok} of {sto.total} realizations ok; seed 002, Figs. 29-32)",
                 fontsize="medium")
    _seed_footnote(fig)
    return fig


def _fig_bar_fields(res: GamutResult, solver_class):
    """The bar with its field realizations (solvers/gamut_bar/bar_figure.py)."""
    bar = solver_class.from_scene(res.scene)
    note = ""
    if res.source != "study" and res.stochastic:
        note = f"field realizations not drawn: {_without_study_text(dict(res.tree.attrs))}"
    realizations = field_realizations(bar, res.field_tables, res.runs)
    kind = (f"{len(realizations[0].values)} realizations of its random fields" if realizations
            else "its nominal properties")
    title = f"{res.name}\nthe bar ({res.describe()}) with {kind}"
    return draw_bar(bar, realizations, title, note)


def _figures(results: list[GamutResult], folder: Path, solver_class) -> list[Path]:
    idx = _Index(results)
    seed = seed_tables()
    jobs = [("bar_fields" + ("" if len(results) == 1 else f"_{r.name}"),
             lambda r=r: _fig_bar_fields(r, solver_class))
            for r in (results if solver_class is not None else [])]
    for case, grid in idx.groups("monotonic"):
        slug = (idx.get(case, "monotonic", grid, True)
                or idx.get(case, "monotonic", grid, False)).slug
        jobs.append((f"gamut_bar_{slug}_{grid}_monotonic.png",
                     lambda c=case, g=grid: _fig_monotonic(idx, c, g)))
    for case, grid in idx.groups("cyclic"):
        slug = (idx.get(case, "cyclic", grid, True) or idx.get(case, "cyclic", grid, False)
                or next(r for r in idx.results if r.case == case)).slug
        jobs += [(f"gamut_bar_{slug}_{grid}_cyclic_loops.png",
                  lambda c=case, g=grid: _fig_loops(idx, c, g)),
                 (f"gamut_bar_{slug}_{grid}_cyclic_loglog.png",
                  lambda c=case, g=grid: _fig_loglog(idx, c, g)),
                 (f"gamut_bar_{slug}_{grid}_cyclic_constants.png",
                  lambda c=case, g=grid: _fig_constants(idx, c, g, seed))]
    written = []
    for name, draw in jobs:
        try:
            fig = draw()
        except Exception as exc:  # one broken figure must not cost the others
            warnings.warn(f"figure {name} not written: {type(exc).__name__}: {exc}",
                          FigureWarning, stacklevel=2)
            continue
        if fig is not None:
            Path(folder).mkdir(parents=True, exist_ok=True)
            written.append(save_figure(fig, figure_path(folder, name.removesuffix(".png"))))
    return written


# ------------------------------------------------------------------------------ the hook

def report(trees, folder, figures: bool = True, *, solver_class,
           bar_fields: bool = True) -> tuple[str, list[Path]]:
    """Seed 002's comparisons for any set of gamut-bar results: the text (Table 1 with ours
    beside the seed's numbers, n'/K' spread, failure, mean monotonic curves) and the PNG
    figures written into ``folder`` (none with ``figures=False``): the bar with its field
    realizations (``bar_fields.png``; ``bar_fields_<study>.png`` for several results), and
    the seed's figures. ``solver_class``: the gamut-bar solver (``GamutBarSolver.report``
    passes itself), which builds each result's bar from its scene; ``bar_fields=False``: the
    seed's figures only (``benchmarks/gamut_bar_table1.py``)."""
    found = [r for r in map(identify, trees) if r is not None]
    results = [r for r in found if r.source]
    left_out = [f"note: {r.name}: {_without_study_text(dict(r.tree.attrs))}, and the solver's "
                f"description names no case: left out" for r in found if not r.source]
    if not results:
        return "\n".join(left_out), []
    text = "\n\n".join([SEED_LINE] + [t.text() for t in _tables(results)]
                       + (["\n".join(left_out)] if left_out else []))
    pngs = _figures(results, Path(folder), solver_class if bar_fields else None) \
        if figures else []
    return text, pngs
