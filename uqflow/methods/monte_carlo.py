"""Monte Carlo: sample the inputs, run every sample, estimate moments with their error."""

from __future__ import annotations

from typing import Literal

import numpy as np
import xarray as xr
from pydantic import Field, field_validator
from scipy import stats as sps

from uqflow.methods.base import (MethodOptions, PropagationMethod, failure_warning,
                                 finish_statistics, make_design, ok_mask, output_names,
                                 register_method)
from uqflow.sampling import unit_hypercube


class SampleStatisticsOptions(MethodOptions):
    """What every sampling method estimates and when it may stop (shared by kl-weibull)."""

    quantiles: list[float] = Field(default_factory=lambda: [0.05, 0.5, 0.95])
    confidence: float = Field(0.95, gt=0, lt=1, description="level of the mean's interval")
    target_rel_stderr: float | None = Field(
        None, gt=0, description="stop once stderr/|mean| of every output is below this")
    min_samples: int = Field(32, ge=2, description="never stop on target before this many")
    trace_points: int = Field(25, ge=2, description="sample counts in the convergence trace")

    @field_validator("quantiles")
    @classmethod
    def _quantiles_in_unit_interval(cls, q):
        if any(not 0 <= x <= 1 for x in q):
            raise ValueError("every quantile must lie in [0, 1]")
        return sorted(set(q))


class MonteCarloOptions(SampleStatisticsOptions):
    samples: int = Field(1000, ge=1, description="number of realizations (the most run)")
    rule: Literal["random", "lhs", "sobol", "halton"] = "random"


@register_method("monte-carlo")
class MonteCarlo(PropagationMethod):
    """Monte Carlo sampling (random, LHS, scrambled Sobol or Halton) with error estimates."""

    Options = MonteCarloOptions

    def plan(self, space, fields, seed):
        self.check(space, fields)
        u = unit_hypercube(self.options.rule, self.options.samples, len(space), seed)
        design = make_design(space, space.from_unit_hypercube(u))
        design.attrs["rule"] = self.options.rule
        return design

    def stop_points(self, n_planned):
        # Checks about 9 % apart: the overshoot past the first sufficient count stays below
        # that, and the number of checks grows only with log(n).
        if self.options.target_rel_stderr is None:
            return np.zeros(0, dtype=np.int64)
        first = min(self.options.min_samples, n_planned)
        k_max = int(np.ceil(8 * np.log2(max(n_planned / first, 1.0))))
        counts = np.ceil(first * 2.0 ** (np.arange(k_max + 1) / 8)).astype(np.int64)
        return np.unique(np.minimum(counts, n_planned))

    def enough(self, design, runs):
        target = self.options.target_rel_stderr
        ok = ok_mask(runs)
        if target is None or ok.sum() < self.options.min_samples:
            return False
        for out in output_names(runs):
            y = runs[out].values[ok]
            mean, var = _mean_var(y)
            stderr = np.sqrt(var / y.shape[0])
            # A field output is judged against its largest |mean|: elements crossing zero
            # would otherwise never reach any relative target.
            scale = np.maximum(np.abs(mean), np.max(np.abs(mean)))
            with np.errstate(divide="ignore", invalid="ignore"):
                rel = np.where(stderr == 0, 0.0, stderr / scale)
            if not np.all(rel <= target):
                return False
        return True

    def analyze(self, design, runs):
        ok = ok_mask(runs)
        n = int(ok.sum())
        opts = self.options
        q_labels = [f"q{100 * q:g}" for q in opts.quantiles]
        labels = ["mean", "variance", "std", "stderr", "ci_low", "ci_high", *q_labels]
        t = sps.t.ppf(0.5 + opts.confidence / 2, n - 1) if n > 1 else np.nan
        data = {}
        for out in output_names(runs):
            y = runs[out].values[ok]
            dims = runs[out].dims[1:]
            if n == 0:
                block = np.full((len(labels),) + runs[out].shape[1:], np.nan)
            else:
                mean, var = _mean_var(y)
                std = np.sqrt(var)
                stderr = std / np.sqrt(n)
                quant = np.quantile(y, opts.quantiles, axis=0)
                block = np.stack([mean, var, std, stderr, mean - t * stderr, mean + t * stderr,
                                  *quant])
            data[out] = (("statistic", *dims), block)
            data[f"{out}_trace"], counts = self._trace(y, dims)
        coords = {"statistic": labels, "trace_statistic": ["mean", "std", "stderr"]}
        if data:
            coords["trace_samples"] = counts
        stats = xr.Dataset(data, coords=coords)
        stats = stats.assign_coords({d: runs[d] for d in runs.coords
                                     if d not in ("realization",) and d in stats.dims})
        warnings = failure_warning(runs)
        if n < 2:
            warnings.append(f"only {n} realization(s) succeeded: no variance can be estimated")
        stats = finish_statistics(stats, design, runs, self.name, warnings)
        stats.attrs.update(rule=design.attrs.get("rule", opts.rule), samples_ok=n,
                           confidence=opts.confidence)
        return stats

    def _trace(self, y, dims):
        """Running mean, std and standard error after the first n realizations, n log-spaced."""
        n = y.shape[0]
        if n < 2:
            counts = np.array([max(n, 1)])
            block = np.full((1, 3) + y.shape[1:], np.nan)
            if n == 1:
                block[0, 0] = y[0]
            return (("trace_samples", "trace_statistic", *dims), block,
                    {"long_name": "running estimates against sample count"}), counts
        counts = np.unique(np.round(np.geomspace(2, n, self.options.trace_points)).astype(int))
        # Centre on the overall mean so the running sums keep their digits at any magnitude.
        centred = y - y.mean(axis=0)
        s1 = np.cumsum(centred, axis=0)[counts - 1]
        s2 = np.cumsum(centred**2, axis=0)[counts - 1]
        shape = (-1,) + (1,) * (y.ndim - 1)
        c = counts.reshape(shape).astype(float)
        mean = y.mean(axis=0) + s1 / c
        var = np.maximum(s2 - s1**2 / c, 0.0) / (c - 1)
        # Prefixes of equal values: exactly their value and variance 0 (not rounding noise).
        const = (np.minimum.accumulate(y, axis=0) == np.maximum.accumulate(y, axis=0))[counts - 1]
        mean = np.where(const, y[0], mean)
        var = np.where(const, 0.0, var)
        block = np.stack([mean, np.sqrt(var), np.sqrt(var / c)], axis=1)
        return (("trace_samples", "trace_statistic", *dims), block,
                {"long_name": "running estimates against sample count"}), counts


def _mean_var(y):
    """Mean and unbiased variance over axis 0 (NaN variance below two samples).

    Columns whose values are all equal (zero-std inputs, an output that does not depend on
    them) get exactly that value and variance 0: the two-pass formula leaves ~1e-32 of
    rounding noise there, which would read as a (tiny) error estimate.
    """
    n = y.shape[0]
    mean = y.mean(axis=0)
    var = y.var(axis=0, ddof=1) if n > 1 else np.full(np.shape(mean), np.nan)
    const = np.all(y == y[0], axis=0)
    return np.where(const, y[0], mean), np.where(const & (n > 1), 0.0, var)
