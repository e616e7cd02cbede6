"""Multilevel Monte Carlo (Giles): the finest level's mean and variance from mostly coarse runs.

Correction l (l = 0 .. L, coarsest first) is Y_0 = P_0 or Y_l = P_l - P_{l-1}, the two runs of
a sample at adjacent levels with the same inputs and realization seed. A pilot of ``pilot``
samples per correction estimates V_l = Var[Y_l] and the cost C_l of a sample (c_l + c_{l-1}
for a pair); Giles' allocation then gives the counts that reach the target variance
theta eps^2 (theta = ``variance_share``) at the least cost, re-planned after each round with
all the samples so far, until no correction needs more (or ``max_rounds``). The rest of the
mean-square error, (1 - theta) eps^2, is the finest level's bias, estimated from the last
corrections' means and the fitted rate alpha: a warning says when it is larger.

A pair with a failed run is dropped from its correction (both runs), counted per level and
warned about: dropping biases the estimate when failures depend on the inputs.

Statistics per output point: mean, variance (the multilevel sum of differences of unbiased
sample variances), std, stderr (sqrt(sum V_l / N_l)), ci_low/ci_high (normal), variance_stderr
(first order), bias (estimated), rmse (sqrt(stderr^2 + bias^2)); per level: ``level_samples``,
``level_failed_pairs``, ``level_run_cost``, ``level_sample_cost``, ``{out}_level_mean``,
``{out}_level_variance``; ``{out}_rates`` (alpha, beta) and attribute ``gamma``;
``{out}_equivalent_runs`` (finest-level plain MC runs for the same stderr) and
``{out}_cost_ratio`` (their cost over this study's). docs/multilevel.md.
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from pydantic import Field
from scipy import stats as sps

from uqflow.levels import LEVEL_VARIABLE
from uqflow.layout import (LEVEL, ROUND, SOLVER_RUNS, STATISTIC, STATISTIC_CI_HIGH,
                           STATISTIC_CI_LOW, STATISTIC_MEAN, STATISTIC_STD, STATISTIC_STDERR,
                           STATISTIC_VARIANCE, STATUS, STATUS_OK, UNITS)
from uqflow.methods import level_report
from uqflow.methods.base import finish_statistics, output_names, register_method
from uqflow.methods.fidelity_sampling import (FidelityOptions, FidelitySampling, flat,
                                              output_shape, point_label)
from uqflow.methods.multilevel_estimators import (giles_counts, level_rate, mlmc_bias,
                                                  mlmc_level_terms, nan_moments_quietly)


class MultilevelOptions(FidelityOptions):
    variance_share: float = Field(0.5, gt=0, lt=1, description="share theta of the target "
                                  "mean-square error given to the sampling variance")


@register_method("multilevel")
class Multilevel(FidelitySampling):
    """Multilevel Monte Carlo over the study's [levels] (Giles' allocation, re-planned)."""

    Options = MultilevelOptions

    def pilot_design(self) -> xr.Dataset:
        n = self.options.pilot
        return self.rows(self._blocks(np.zeros(self.n_levels, dtype=np.int64),
                                      np.full(self.n_levels, n)), 0)

    def _blocks(self, start, stop):
        # fine runs of a correction, then its coarse runs: batches stay on one level
        blocks = []
        for l in range(self.n_levels):
            blocks.append((l, l, l, int(start[l]), int(stop[l])))
            if l:
                blocks.append((l - 1, l, l, int(start[l]), int(stop[l])))
        return blocks

    # --- pairing ----------------------------------------------------------------------------

    def pairs(self, runs: xr.Dataset):
        """Per correction: (fine rows, coarse rows or None, drawn samples, failed pairs),
        rows of the successful pairs matched by sample."""
        level = runs[LEVEL_VARIABLE].values
        group = runs["group"].values
        sample = runs["sample"].values
        ok = runs[STATUS].values == STATUS_OK
        out = []
        for l in range(self.n_levels):
            fine = np.flatnonzero((group == l) & (level == l))
            fine = fine[np.argsort(sample[fine], kind="stable")]
            if l == 0:
                good = ok[fine]
                out.append((fine[good], None, fine.size, int((~good).sum())))
                continue
            coarse = np.flatnonzero((group == l) & (level == l - 1))
            coarse = coarse[np.argsort(sample[coarse], kind="stable")]
            good = ok[fine] & ok[coarse]
            out.append((fine[good], coarse[good], fine.size, int((~good).sum())))
        return out

    def level_terms(self, runs: xr.Dataset, name: str, pairs) -> list[dict]:
        return [mlmc_level_terms(flat(runs, name, fine),
                                 None if coarse is None else flat(runs, name, coarse))
                for fine, coarse, _, _ in pairs]

    # --- re-planning ------------------------------------------------------------------------

    def extend(self, design, runs):
        rounds = int(runs[ROUND].values.max())
        if rounds >= self.options.max_rounds:
            return None
        pairs = self.pairs(runs)
        drawn = np.array([p[2] for p in pairs])
        # the allocation depends on the costs' ratios alone: scaled to the dearest, a stated
        # cost of 1e300 or 1e-300 neither overflows nor underflows in the sums
        c = self.run_costs(runs)
        c = c / c.max()
        C = c + np.concatenate([[0.0], c[:-1]])
        V, target = [], []
        means = {}
        for name in self.allocating(runs):
            terms = self.level_terms(runs, name, pairs)
            means[name] = np.sum([t["mean"] for t in terms], axis=0)
            V.append(np.stack([t["V"] for t in terms]))
        for name, eps2 in self.variance_targets(means, runs).items():
            target.append(eps2 * self.options.variance_share)
        wanted = giles_counts(np.concatenate(V, axis=1), C, np.concatenate(target),
                              most=self.options.max_samples)
        if not np.any(wanted > drawn):
            return None
        return self.rows(self._blocks(drawn, np.maximum(wanted, drawn)), rounds + 1)

    # --- statistics -------------------------------------------------------------------------

    def analyze(self, design, runs):
        pairs = self.pairs(runs)
        n = np.array([fine.size for fine, _, _, _ in pairs])
        failed = np.array([p[3] for p in pairs])
        c = self.run_costs(runs)
        C = c + np.concatenate([[0.0], c[:-1]])
        z = float(sps.norm.ppf(0.5 + self.options.confidence / 2))
        theta = self.options.variance_share
        gamma = level_rate(c, decreasing=False)
        data, warnings = {}, []
        means = {}
        for name in output_names(runs):
            dims, shape = output_shape(runs, name)
            terms = self.level_terms(runs, name, pairs)
            E = np.stack([t["mean"] for t in terms])
            V = np.stack([t["V"] for t in terms])
            mean = E.sum(axis=0)
            means[name] = mean
            with np.errstate(invalid="ignore", divide="ignore"):
                stderr = np.sqrt(np.sum(V / n[:, None], axis=0))
            variance = np.sum([t["var_term"] for t in terms], axis=0)
            variance_se = np.sqrt(np.sum([t["var_term_var"] for t in terms], axis=0))
            with nan_moments_quietly():  # a level whose runs all failed is NaN
                alpha = level_rate(np.nanmax(np.abs(E), axis=1))
                beta = level_rate(np.nanmax(V, axis=1))
            bias = mlmc_bias(E, alpha)
            rmse = np.sqrt(stderr**2 + bias**2)
            std = np.sqrt(np.maximum(variance, 0.0))
            stat = np.stack([mean, variance, std, stderr, mean - z * stderr, mean + z * stderr,
                             variance_se, bias, rmse])
            data[name] = ((STATISTIC, *dims), stat.reshape(len(stat), *shape))
            data[f"{name}_level_mean"] = ((LEVEL, *dims), E.reshape(len(E), *shape))
            data[f"{name}_level_variance"] = ((LEVEL, *dims), V.reshape(len(V), *shape))
            data[f"{name}_rates"] = (("rate",), np.array([alpha, beta]))
            # finest-level plain MC with the same stderr: Var[P_L] / stderr^2 runs of c_L
            with np.errstate(invalid="ignore", divide="ignore"):
                equivalent = np.maximum(variance, 0.0) / stderr**2
                ratio = equivalent * c[-1] / float(np.dot(n, C))
            data[f"{name}_equivalent_runs"] = (dims, equivalent.reshape(shape))
            data[f"{name}_cost_ratio"] = (dims, ratio.reshape(shape))
            if not np.isfinite(alpha):
                warnings.append(f"{name}: the bias rate alpha could not be fitted (fewer than "
                                f"two correction levels with a nonzero mean); the bias "
                                f"estimate assumes first order (alpha = 1)")
        targets = self.variance_targets({k: means[k] for k in self.allocating(runs)}, runs)
        drawn = np.array([p[2] for p in pairs])
        for name, eps2 in targets.items():
            stat = data[name][1].reshape(9, -1)
            bias, stderr = stat[7], stat[3]
            with np.errstate(invalid="ignore"):
                over = np.flatnonzero(bias**2 > (1 - theta) * eps2)
            if over.size:
                k = int(over[np.argmax(bias[over])])
                warnings.append(f"{point_label(runs, name, k)}: the finest level's "
                                f"estimated bias {bias[k]:.3g} exceeds its share of the "
                                f"target, sqrt(1 - theta) eps = "
                                f"{np.sqrt((1 - theta) * eps2[k]):.3g}: add a finer level")
            short = self.target_not_met(runs, name, stderr, theta * eps2, drawn)
            if short:
                warnings.append(short)
        if failed.any():
            warnings.append(f"failed pairs dropped per level {failed.tolist()} (a pair with a "
                            f"failed run at either level leaves its correction); the "
                            f"statistics use the others, which biases them if failures "
                            f"depend on the inputs")
        coords = {STATISTIC: [STATISTIC_MEAN, STATISTIC_VARIANCE, STATISTIC_STD, STATISTIC_STDERR,
                              STATISTIC_CI_LOW, STATISTIC_CI_HIGH, "variance_stderr",
                              level_report.BIAS, level_report.RMSE],
                  LEVEL: np.arange(self.n_levels), "rate": ["alpha", "beta"]}
        coords.update({d: runs[d] for name in output_names(runs)
                       for d in output_shape(runs, name)[0] if d in runs.coords})
        stats = xr.Dataset(data, coords=coords)
        stats = stats.assign_coords(level_value=(LEVEL, np.asarray(self.level_values,
                                                                     dtype=float)))
        stats["level_samples"] = (LEVEL, n)
        stats["level_failed_pairs"] = (LEVEL, failed)
        stats["level_run_cost"] = (LEVEL, c, {UNITS: "s" if self.options.costs ==
                                                "measured" else "stated"})
        stats["level_sample_cost"] = (LEVEL, C, dict(stats["level_run_cost"].attrs))
        stats.attrs.update(gamma=gamma, variance_share=theta, rounds=int(
            runs[ROUND].values.max()) + 1, total_cost=float(np.dot(n + failed, C)))
        return finish_statistics(stats, design, runs, self.name, warnings)

    @classmethod
    def report(cls, view):
        """How sure each output's estimate is and what it saved, the level table and the
        levels figure; the runs are at several levels, not draws of the finest one."""
        runs = int(view.stats.attrs.get(SOLVER_RUNS, 0))
        count = view.stats.sizes.get(LEVEL, 0)
        return level_report.level_report(
            view, f"Multilevel Monte Carlo, {count} level{'' if count == 1 else 's'}, {runs} "
                  f"run{'' if runs == 1 else 's'}")

    #: one comparison for multilevel and multifidelity results (``compare_results`` asks it
    #: once): the error each result bought against its solver time, beside plain Monte Carlo
    compare = classmethod(level_report.compare)
