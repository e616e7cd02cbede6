"""Multifidelity Monte Carlo (Peherstorfer, Willcox & Gunzburger 2016): the finest level is
the high-fidelity model, the coarser levels its cheaper correlated models.

Every model runs on one sample sequence, model i on samples 0 .. m_i - 1 with m_1 (finest)
the smallest. A pilot runs ``pilot`` samples on every model and measures (or takes) the costs;
per allocating point the correlations rho_i and std s_1 give the optimal ratios r_i and the
subset of models that pays (the ordering and cost conditions of PWG 2016, Thm. 3.4, checked
over every subset that keeps the level order), and m_1 from the target variance eps^2:
Var[s] = s_1^2 / m_1 (1 - sum (1/r_{i-1} - 1/r_i) rho_i^2). The counts are the largest over
the points, re-planned with all samples after each round (counts only grow).

Estimates per point: the MFMC mean and its plug-in variance (``stderr``), the variance as the
MFMC estimate of E[f^2] minus mean^2 plus Var[mean] (first-order bias corrected), the
equivalent plain-MC count s_1^2 / Var[s] at the finest level and its cost over this study's
(``{out}_cost_ratio``); per model: ``model_samples``, ``{out}_correlation``,
``{out}_weight`` (alpha_i). A sample with a failed run at any model is dropped from every
model (the estimator needs nested samples), counted and warned about. The estimator is
unbiased for fixed alpha; alpha estimated from the samples adds an O(1/m_1) bias, and the
pilot both allocates and estimates (stated in docs/multilevel.md).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import xarray as xr
from pydantic import Field
from scipy import stats as sps

from uqflow.errors import StudyError
from uqflow.levels import LEVEL_VARIABLE
from uqflow.methods import control_variate as cv
from uqflow.layout import (INPUTS, REALIZATION, ROUND, SOLVER_RUNS, STATISTIC, STATISTIC_CI_HIGH,
                           STATISTIC_CI_LOW, STATISTIC_MEAN, STATISTIC_STD, STATISTIC_STDERR,
                           STATISTIC_VARIANCE, STATUS, STATUS_OK, UNITS)
from uqflow.methods import level_report
from uqflow.methods.base import finish_statistics, output_names, register_method
from uqflow.methods.fidelity_sampling import (FidelityOptions, FidelitySampling, flat,
                                              output_shape)
from uqflow.methods.multilevel_estimators import (mfmc_allocation, mfmc_estimate,
                                                  nan_moments_quietly)
from uqflow.realization import SENSITIVITY_FLAG

#: all models draw from one stream: the same sample k at every level
STREAM = 0
#: the surrogate's run (at the input means) has a seed key of its own
SURROGATE_STREAM = 1


def _surrogate_error(err: StudyError) -> StudyError:
    """The control variates' refusal of the Taylor surrogate, in this method's words: the
    key is ``method.surrogate``, the alternative ``surrogate = "none"``."""
    return StudyError(err.reason.replace("control = \"taylor\"", "no surrogate")
                      .replace("use control = \"none\"", "use surrogate = \"none\"")
                      .replace("use control", "use surrogate")
                      .replace("a control needs", "the surrogate needs"),
                      key="method.surrogate")


def pointwise_correlation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Correlation of the columns of ``a`` and ``b`` (n, points), point by point (NaN where
    either is constant)."""
    with nan_moments_quietly():
        da, db = a - a.mean(axis=0), b - b.mean(axis=0)
        return (da * db).sum(axis=0) / np.sqrt((da**2).sum(axis=0) * (db**2).sum(axis=0))


class MultifidelityOptions(FidelityOptions):
    surrogate: Literal["none", "taylor-local"] = Field(
        "none", description="add the second-order Taylor polynomial of the finest level from "
                            "one run with the solver's local derivatives, as a free model "
                            "whose mean is known")


@register_method("multifidelity")
class Multifidelity(FidelitySampling):
    """Multifidelity Monte Carlo over the study's [levels], finest = high fidelity."""

    Options = MultifidelityOptions

    @property
    def surrogate(self) -> bool:
        return self.options.surrogate == "taylor-local"

    def check(self, space, fields):
        super().check(space, fields)
        if self.surrogate:
            try:
                cv.check_space("taylor-local", 0.1, space)
            except StudyError as err:
                raise _surrogate_error(err) from None

    def check_solver(self, solver, outputs, parameter_names):
        super().check_solver(solver, outputs, parameter_names)
        if self.surrogate:
            try:
                cv.check_solver("taylor-local", solver, outputs, parameter_names)
            except StudyError as err:
                raise _surrogate_error(err) from None

    def pilot_design(self) -> xr.Dataset:
        n = self.options.pilot
        design = self.rows([(lv, self.model_of(lv), STREAM, 0, n)
                            for lv in reversed(range(self.n_levels))], 0)
        if not self.surrogate:
            return design
        # the surrogate's one run at the input means, first (control_variate's layout), at
        # the finest level
        head = self.rows([(self.n_levels - 1, -1, SURROGATE_STREAM, 0, 1)], 0)
        head[INPUTS].values[:] = self._space.means
        head[SENSITIVITY_FLAG].values[:] = True
        head = head.assign_coords({cv.ROLE: (REALIZATION, np.array(["control"], dtype=object))})
        design = xr.concat([head, design.assign_coords(realization=design.realization + 1)],
                           dim=REALIZATION, data_vars="minimal", coords="minimal",
                           compat="override", join="override")
        active = np.flatnonzero(self._space.stds > 0)
        design.attrs.update(control="taylor-local", control_runs=1, normal_inputs=int(
            all(self._space.inputs[k].kind == "normal" for k in active)))
        return design

    def rows(self, blocks, round_):
        design = super().rows(blocks, round_)
        if self.surrogate:
            n = design.sizes[REALIZATION]
            design[SENSITIVITY_FLAG] = (REALIZATION, np.zeros(n, dtype=bool))
            design = design.assign_coords({cv.ROLE: (REALIZATION,
                                                     np.full(n, "sample", dtype=object))})
        return design

    def surrogates(self, design, runs):
        """The Taylor surrogate of every output, or None (none asked, or its run failed:
        then the method goes on without it, and says so)."""
        if not self.surrogate:
            return None
        try:
            return cv.build_surrogates(design, runs)
        except cv.ControlFailed as exc:
            self._surrogate_failure = str(exc)
            return None

    def model_of(self, level: int) -> int:
        """Model index (0 = high fidelity = finest level) of ``level``."""
        return self.n_levels - 1 - level

    def samples(self, runs: xr.Dataset):
        """Per model, the rows of samples 0.. in order, the usable sample count (a prefix
        without a failed sample), and the number of samples dropped for failures."""
        level = runs[LEVEL_VARIABLE].values
        sample = runs["sample"].values
        status = runs[STATUS].values
        model_row = runs["group"].values >= 0          # not the surrogate's run
        bad = set(sample[(status != STATUS_OK) & model_row].tolist())
        rows, drawn = [], []
        for model in range(self.n_levels):
            mine = np.flatnonzero((level == self.n_levels - 1 - model) & model_row)
            mine = mine[np.argsort(sample[mine], kind="stable")]
            drawn.append(mine.size)
            rows.append(mine[[s not in bad for s in sample[mine]]])
        return rows, np.array(drawn), len(bad)

    def model_values(self, runs: xr.Dataset, name: str, rows, surrogate=None):
        """Each model's values (n_i, points) on its samples, finest first; the surrogate's,
        if any, last, at every sample drawn (it costs nothing)."""
        values = [flat(runs, name, r) for r in rows]
        if surrogate is not None:
            widest = rows[int(np.argmax([r.size for r in rows]))]
            values.append(surrogate[name](runs[INPUTS].values[widest]))
        return values

    def estimates(self, runs: xr.Dataset, name: str, rows, power: int = 1, surrogate=None):
        values = [v ** power for v in self.model_values(runs, name, rows)]
        counts = [v.shape[0] for v in values]
        if surrogate is None:
            return mfmc_estimate(values, counts)
        g = self.model_values(runs, name, rows, surrogate)[-1] ** power
        sg = surrogate[name]
        # E[g] and E[g^2] = Var g + E[g]^2 are closed-form (docs/control_variates.md)
        exact = sg.mean if power == 1 else sg.variance + sg.mean**2
        return mfmc_estimate(values + [g], counts + [math.inf], exact_mean=exact)

    def model_costs(self, runs):
        """Cost per run of each model, finest first; 0 for the surrogate."""
        c = self.run_costs(runs)
        w = [c[self.n_levels - 1 - m] for m in range(self.n_levels)]
        return np.array(w + ([0.0] if self.surrogate else []))

    # --- re-planning ------------------------------------------------------------------------

    def extend(self, design, runs):
        rounds = int(runs[ROUND].values.max())
        if rounds >= self.options.max_rounds:
            return None
        rows, drawn, _ = self.samples(runs)
        surrogate = self.surrogates(design, runs)
        # the allocation depends on the costs' ratios alone: scaled to the dearest, a stated
        # cost of 1e300 or 1e-300 neither overflows nor underflows
        w = self.model_costs(runs)
        w = w / w.max()
        if surrogate is None:
            w = w[:self.n_levels]
        wanted = np.zeros(w.size, dtype=np.int64)
        means = {name: self.estimates(runs, name, rows, surrogate=surrogate)["mean"]
                 for name in self.allocating(runs)}
        for name, eps2 in self.variance_targets(means, runs).items():
            values = self.model_values(runs, name, rows, surrogate)
            shared = min(v.shape[0] for v in values)
            y = np.stack([v[:shared] for v in values])                    # (models, n, points)
            with nan_moments_quietly():  # fewer than two samples: skipped below
                s = y.std(axis=1, ddof=1)
            rho = np.stack([pointwise_correlation(y[0], y[m]) for m in range(len(values))])
            for p in range(y.shape[2]):
                if not s[0, p] > 0 or not np.isfinite(eps2[p]) or not eps2[p] > 0:
                    continue
                r = np.nan_to_num(rho[:, p], nan=0.0)
                got = mfmc_allocation(float(s[0, p]), r, w, float(eps2[p]),
                                      most=self.options.max_samples)
                if got is not None:
                    wanted = np.maximum(wanted, got)
        wanted = np.minimum(wanted[:self.n_levels], self.options.max_samples)
        # nested: a model that is used runs at least the samples of the models before it
        for m in range(1, self.n_levels):
            if wanted[m] > 0:
                wanted[m] = max(wanted[m], wanted[:m].max())
        if not np.any(wanted > drawn):
            return None
        blocks = [(self.n_levels - 1 - m, m, STREAM, int(drawn[m]), int(max(wanted[m],
                                                                            drawn[m])))
                  for m in range(self.n_levels)]
        return self.rows(blocks, rounds + 1)

    # --- statistics -------------------------------------------------------------------------

    def analyze(self, design, runs):
        rows, drawn, dropped = self.samples(runs)
        self._surrogate_failure = None
        surrogate = self.surrogates(design, runs)
        counts = np.array([r.size for r in rows])
        w = self.model_costs(runs)
        # what was spent: every model's runs, and the surrogate's one run at the finest level
        spent = float(np.dot(drawn, w[:self.n_levels])) + (w[0] if self.surrogate else 0.0)
        if surrogate is None:
            w = w[:self.n_levels]
        models = w.size
        z = float(sps.norm.ppf(0.5 + self.options.confidence / 2))
        data, warnings = {}, []
        if self._surrogate_failure:
            warnings.append(f"the Taylor surrogate is left out: {self._surrogate_failure}")
        for name in output_names(runs):
            dims, shape = output_shape(runs, name)
            first = self.estimates(runs, name, rows, surrogate=surrogate)
            second = self.estimates(runs, name, rows, power=2, surrogate=surrogate)
            mean, var_mean = first["mean"], first["variance"]
            stderr = np.sqrt(var_mean)
            variance = second["mean"] - mean**2 + var_mean
            std = np.sqrt(np.maximum(variance, 0.0))
            stat = np.stack([mean, variance, std, stderr, mean - z * stderr, mean + z * stderr])
            data[name] = ((STATISTIC, *dims), stat.reshape(len(stat), *shape))
            values = self.model_values(runs, name, rows, surrogate)
            shared = min(v.shape[0] for v in values)
            rho = np.stack([pointwise_correlation(values[0][:shared], v[:shared])
                            for v in values])
            with np.errstate(invalid="ignore", divide="ignore"):
                equivalent = first["sigma"] ** 2 / var_mean
                ratio = equivalent * w[0] / spent
            data[f"{name}_correlation"] = (("model", *dims), rho.reshape(len(rho), *shape))
            data[f"{name}_weight"] = (("model", *dims), np.stack(
                [np.ones(first["mean"].shape), *first["alpha"]]).reshape(models, *shape))
            data[f"{name}_equivalent_runs"] = (dims, equivalent.reshape(shape))
            data[f"{name}_cost_ratio"] = (dims, ratio.reshape(shape))
        if dropped:
            warnings.append(f"{dropped} samples with a failed run at some level were dropped "
                            f"from every model (the estimator needs the same samples at each "
                            f"model); the statistics use the others, which biases them if "
                            f"failures depend on the inputs")
        targets = self.variance_targets({k: data[k][1].reshape(6, -1)[0]
                                         for k in self.allocating(runs)}, runs)
        for name, eps2 in targets.items():
            stderr = data[name][1].reshape(6, -1)[3]
            short = self.target_not_met(runs, name, stderr, eps2, drawn)
            if short:
                warnings.append(short)
        coords = {STATISTIC: [STATISTIC_MEAN, STATISTIC_VARIANCE, STATISTIC_STD, STATISTIC_STDERR,
                              STATISTIC_CI_LOW, STATISTIC_CI_HIGH],
                  "model": np.arange(models)}
        coords.update({d: runs[d] for name in output_names(runs)
                       for d in output_shape(runs, name)[0] if d in runs.coords})
        stats = xr.Dataset(data, coords=coords)
        free = models - self.n_levels       # 1 with the surrogate: level -1, no value
        stats = stats.assign_coords(
            model_level=("model", np.concatenate([np.arange(self.n_levels)[::-1],
                                                  [-1] * free])),
            level_value=("model", np.concatenate([np.asarray(self.level_values,
                                                             dtype=float)[::-1],
                                                  [np.nan] * free])))
        stats["model_samples"] = ("model", np.concatenate([counts, [0] * free]))
        stats["model_run_cost"] = ("model", w, {UNITS: "s" if self.options.costs ==
                                                "measured" else "stated"})
        stats.attrs.update(rounds=int(runs[ROUND].values.max()) + 1,
                           total_cost=spent, dropped_samples=dropped,
                           surrogate=self.options.surrogate if free else "none")
        return finish_statistics(stats, design, runs, self.name, warnings)

    @classmethod
    def report(cls, view):
        """How sure each output's estimate is and what it saved, the model table; the
        runs are at several models, not draws of the finest one."""
        runs = int(view.stats.attrs.get(SOLVER_RUNS, 0))
        count = view.stats.sizes.get(level_report.MODEL, 0)
        return level_report.level_report(
            view, f"Multifidelity Monte Carlo, {count} model{'' if count == 1 else 's'}, "
                  f"{runs} run{'' if runs == 1 else 's'}")

    #: one comparison for multilevel and multifidelity results (``compare_results`` asks it
    #: once): the error each result bought against its solver time, beside plain Monte Carlo
    compare = classmethod(level_report.compare)
