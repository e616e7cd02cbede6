"""Sobol' indices: variance-based sensitivity of every output to every input, with SALib.

The design is Saltelli's: N base samples, each a block of D + 2 consecutive realizations
(A, the D rows AB_i where column i comes from B, then B), or 2D + 2 with second order (the
BA_i rows added before B). ``SALib.sample.sobol`` builds it on the unit hypercube from a
scrambled Sobol' sequence; ``InputSpace.from_unit_hypercube`` maps it to the inputs.
``SALib.analyze.sobol`` turns the outputs into first-order (S1), total (ST) and optionally
second-order (S2) indices with bootstrap confidence half-widths. See docs/sobol.md.
"""

from __future__ import annotations

import warnings

import numpy as np
import xarray as xr
from pydantic import Field
from SALib.analyze import sobol as salib_analyze
from SALib.sample import sobol as salib_sample

from uqflow.errors import StudyError
from uqflow.layout import (CONFIDENCE, PARAMETER, PARAMETER_J, REALIZATION, SOLVER_RUNS, STATISTIC,
                           STATUS, STATUS_OK, UNITS)
from uqflow.methods.base import (MAX_BOOTSTRAP_DRAWS, MAX_REALIZATIONS, MethodOptions,
                                 PropagationMethod, failure_warning, finish_statistics,
                                 make_design, output_names, register_method)
from uqflow.report import Column, MethodReport, Sensitivity

FIRST_LABELS = ["S1", "S1_conf", "ST", "ST_conf"]
SECOND_LABELS = ["S2", "S2_conf"]
#: the first-order and total indices in words, for a legend
INDEX_WORDS = {"S1": "first order S1", "ST": "total ST"}
#: the dim of the indices in a statistics variable ``{out}_sobol`` (sobol and pce)
SOBOL_INDEX = "sobol_index"
#: inputs shown in a row of the summary table's S1/ST column, largest ST first
SHOWN_INPUTS = 4


class SobolOptions(MethodOptions):
    samples: int = Field(1024, ge=2, description=(
        "base sample N; the study runs N(D+2) realizations, N(2D+2) with second order. "
        "Powers of two keep the Sobol' sequence balanced and converge best"))
    second_order: bool = Field(False, description="also estimate pairwise indices S2")
    resamples: int = Field(1000, ge=2, description="bootstrap resamples of the intervals")
    confidence: float = Field(0.95, gt=0, lt=1, description="level of the bootstrap intervals")


def _problem(names: list[str]) -> dict:
    return {"num_vars": len(names), "names": names, "bounds": [[0.0, 1.0]] * len(names)}


@register_method("sobol")
class Sobol(PropagationMethod):
    """Sobol' sensitivity indices (S1, ST, optional S2) by Saltelli sampling, with SALib."""

    Options = SobolOptions

    def check(self, space, fields):
        super().check(space, fields)
        if space.is_correlated:
            raise StudyError("sobol indices assume independent inputs; remove the correlation "
                             "or use monte-carlo", key="method.kind")
        if len(space) == 0:
            raise StudyError("sobol indices need at least one uncertain input", key="inputs")
        n = self.options.samples
        block = 2 * len(space) + 2 if self.options.second_order else len(space) + 2
        if n * block > MAX_REALIZATIONS:
            raise StudyError(f"{n} base samples × {block} realizations each = {n * block:,}, "
                             f"more than the {MAX_REALIZATIONS:,} a study may run",
                             key="method.samples")
        if n * self.options.resamples > MAX_BOOTSTRAP_DRAWS:
            raise StudyError(f"the bootstrap would draw samples × resamples = "
                             f"{n * self.options.resamples:,} indices at once, more than "
                             f"{MAX_BOOTSTRAP_DRAWS:,} (0.8 GiB)", key="method.resamples")

    def plan(self, space, fields, seed):
        self.check(space, fields)
        opts = self.options
        # One draw for the sequence's scrambling, one for the bootstrap in analyze; the
        # bootstrap seed travels with the design so a re-analysis gives the same intervals.
        # SALib's analyze falls back to numpy's global state on a falsy seed, hence the +1.
        state = seed.generate_state(2)
        with warnings.catch_warnings():
            # scipy warns when N is not a power of two: valid, only less balanced.
            warnings.simplefilter("ignore", UserWarning)
            u = salib_sample.sample(_problem(space.names), opts.samples,
                                    calc_second_order=opts.second_order, scramble=True,
                                    seed=int(state[0]))
        design = make_design(space, space.from_unit_hypercube(u))
        d = len(space)
        design.attrs.update(
            samples=opts.samples,
            # ints, not bools: netCDF attributes cannot hold booleans
            second_order=int(opts.second_order),
            block_size=2 * d + 2 if opts.second_order else d + 2,
            bootstrap_seed=int(state[1]) + 1,
        )
        return design

    def analyze(self, design, runs):
        opts = self.options
        names = [str(p) for p in design[PARAMETER].values]
        d = len(names)
        second = bool(design.attrs.get("second_order", opts.second_order))
        step = 2 * d + 2 if second else d + 2
        n_rows = design.sizes[REALIZATION]
        n_base = n_rows // step
        boot_seed = int(design.attrs.get("bootstrap_seed", 1)) or 1
        outs = output_names(runs)
        warnings_ = failure_warning(runs)

        # Outputs on the design's rows; realizations missing from runs count as failed.
        rows = np.asarray(runs[REALIZATION].values, dtype=int)
        good = np.zeros(n_rows, dtype=bool)
        good[rows] = np.asarray(runs[STATUS].values == STATUS_OK)
        values = {}
        for out in outs:
            y = np.full((n_rows, *runs[out].shape[1:]), np.nan)
            y[rows] = runs[out].values
            values[out] = y.reshape(n_rows, -1)
            good &= np.all(np.isfinite(values[out]), axis=1)

        # A failed row breaks its whole Saltelli block: AB_i is only useful next to its A and B.
        keep = good[: n_base * step].reshape(n_base, step).all(axis=1)
        kept = int(keep.sum())
        if kept < n_base:
            warnings_.append(f"{n_base - kept} of {n_base} base samples dropped: each held a "
                             f"failed realization and a Saltelli block needs all {step} runs")
        if kept < 2:
            warnings_.append(f"only {kept} complete base sample(s): sobol indices are NaN")
        row_keep = np.repeat(keep, step)

        data = {}
        problem = _problem(names)
        for out in outs:
            dims = runs[out].dims[1:]
            shape = runs[out].shape[1:]
            y = values[out][: n_base * step][row_keep]
            m = y.shape[1]
            ab = y.reshape(kept, step, m)[:, [0, step - 1]].reshape(2 * kept, m)
            data[out] = ((STATISTIC, *dims), _moments(ab).reshape(3, *shape))

            first = np.full((4, d, m), np.nan)
            pairs = np.full((2, d, d, m), np.nan)
            flat = 0
            for k in range(m) if kept >= 2 else ():
                col = y[:, k]
                # SALib divides by the output's std; a constant output has no indices.
                if np.ptp(col) <= 8 * np.finfo(float).eps * np.abs(col).max():
                    flat += 1
                    continue
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    si = salib_analyze.analyze(problem, col, calc_second_order=second,
                                               num_resamples=opts.resamples,
                                               conf_level=opts.confidence, seed=boot_seed,
                                               print_to_console=False)
                for w in caught:
                    msg = f"{out}: SALib: {' '.join(str(w.message).split())}"
                    if msg not in warnings_:
                        warnings_.append(msg)
                first[:, :, k] = [si[key] for key in FIRST_LABELS]
                if second:
                    pairs[:, :, :, k] = [si[key] for key in SECOND_LABELS]
            if flat:
                where = "" if not shape else f" at {flat} of {m} points"
                warnings_.append(f"{out} has zero variance{where}: its sobol indices are NaN "
                                 f"there (every input constant, or none acts on it)")
            data[f"{out}_sobol"] = (("sobol_index", PARAMETER, *dims),
                                    first.reshape(4, d, *shape),
                                    {"long_name": "first-order and total sobol indices, "
                                                  f"conf = half-width at {opts.confidence:g}"})
            if second:
                data[f"{out}_sobol2"] = (("sobol2_index", PARAMETER, PARAMETER_J, *dims),
                                         pairs.reshape(2, d, d, *shape),
                                         {"long_name": "second-order sobol indices (upper "
                                                       "triangle), conf = half-width"})

        coords = {STATISTIC: ["mean", "variance", "std"], "sobol_index": FIRST_LABELS,
                  PARAMETER: names, PARAMETER_J: names}
        if second:
            coords["sobol2_index"] = SECOND_LABELS
        stats = xr.Dataset(data, coords=coords)
        stats = stats.assign_coords({c: runs[c] for c in runs.coords
                                     if c not in coords and c != REALIZATION
                                     and c in stats.dims})
        # Indices are fractions of the output variance: unitless, unlike the moments.
        for name in stats.data_vars:
            if name.endswith(("_sobol", "_sobol2")):
                stats[name].attrs[UNITS] = ""
        stats = finish_statistics(stats, design, runs, self.name, warnings_)
        stats.attrs.update(samples=n_base, samples_kept=kept, second_order=int(second),
                           confidence=opts.confidence, resamples=opts.resamples)
        return stats

    @classmethod
    def report(cls, view):
        """The leading inputs' S1/ST in the table, the base samples kept beside the cost, and
        the indices with their bootstrap half-widths as sensitivities.

        The runs are not shown as draws: only Saltelli's A and B rows are independent draws
        from the inputs' distribution (the moments in the table come from them alone); each
        mixed row AB_i copies all but one column of A, so counting every run would weigh each
        base sample d + 2 times over dependent copies and give a scatter that is not the
        table's."""
        stats = view.stats
        kept = stats.attrs.get("samples_kept", "?")
        samples, runs = stats.attrs.get("samples"), int(stats.attrs.get(SOLVER_RUNS, 0))
        return MethodReport(
            description=f"Sobol' indices (Saltelli's design), {samples} base samples, "
                        f"{runs} runs",
            columns=[Column("S1/ST per input (largest ST first)",
                            lambda out, focus: leading_inputs(stats, out, focus))],
            cost_details=[f"{samples} base samples, {kept} kept"] if samples is not None
            else [],
            sensitivities=lambda out: bootstrapped_indices(stats, out))


def leading_inputs(stats, out: str, focus: dict) -> str:
    """'x1 0.31/0.56, x2 0.44/0.44, ...': S1/ST of the inputs with the largest ST."""
    var = f"{out}_sobol"
    if var not in stats:
        return "-"
    si = stats[var].isel(focus)
    params = [str(p) for p in si[PARAMETER].values]
    s1 = si.sel({SOBOL_INDEX: "S1"}).values
    st = si.sel({SOBOL_INDEX: "ST"}).values
    order = sorted(range(len(params)), key=lambda k: -st[k] if np.isfinite(st[k]) else np.inf)
    shown = [f"{params[k]} {s1[k]:.2f}/{st[k]:.2f}" for k in order[:SHOWN_INPUTS]]
    if len(params) > SHOWN_INPUTS:
        shown.append(f"+{len(params) - SHOWN_INPUTS} more")
    return ", ".join(shown)


def sobol_indices(si, title: str, errors=None, error_label: str = "",
                  note: str = "") -> Sensitivity:
    """S1 and ST of ``si`` (``sobol_index``, ``parameter``, *dims) as a ``Sensitivity``;
    ``errors`` alike, with the ``S1_conf``, ``ST_conf`` half-widths."""
    def words(a):
        a = a.sel({SOBOL_INDEX: list(INDEX_WORDS)})
        a = a.assign_coords({SOBOL_INDEX: list(INDEX_WORDS.values())})
        return a.rename({SOBOL_INDEX: "index"}).transpose(PARAMETER, "index", ...)

    return Sensitivity(title=title, values=words(si), quantity="fraction of the variance",
                       errors=None if errors is None else words(errors),
                       error_label=error_label, note=note)


def bootstrapped_indices(stats, out: str) -> Sensitivity | None:
    """The first-order and total indices of ``out``, their errors the bootstrap
    half-widths."""
    var = f"{out}_sobol"
    if var not in stats:
        return None
    si = stats[var]
    # SALib's half-widths are a percentile spread, |.| of it as the figure always drew
    half = abs(si.sel({SOBOL_INDEX: ["S1_conf", "ST_conf"]})).assign_coords(
        {SOBOL_INDEX: ["S1", "ST"]})
    level = float(stats.attrs.get(CONFIDENCE, 0.95))
    return sobol_indices(si, "Sobol' indices", errors=half,
                         error_label=f"{100 * level:g} % bootstrap half-width")


def _moments(y: np.ndarray) -> np.ndarray:
    """Mean, variance and std (rows) of the A and B rows ``y`` (n, m): plain input samples."""
    n, m = y.shape
    mean = y.mean(axis=0) if n else np.full(m, np.nan)
    var = y.var(axis=0, ddof=1) if n > 1 else np.full(m, np.nan)
    return np.stack([mean, var, np.sqrt(var)])
