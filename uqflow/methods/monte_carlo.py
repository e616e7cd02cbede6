"""Monte Carlo: sample the inputs, run every sample, estimate moments with their error.

The standard error of the mean depends on the rule (see docs/inputs.md, "Error of the mean"):

* ``random``: the i.i.d. formula s / sqrt(n), a Student t interval with n - 1 degrees of freedom.
* ``lhs``: the same formula, which is conservative: a Latin hypercube mean has variance at most
  N / (N - 1) times the i.i.d. one (Owen 1997), and usually far less.
* ``sobol``/``halton`` (randomized QMC): the design is ``replicates`` independent scramblings,
  interleaved (realization j R + r is point j of replicate r). The mean is the mean of the R
  replicate means, its standard error their spread / sqrt(R), its interval a Student t with
  R - 1 degrees of freedom. The points of one replicate are not independent, so the i.i.d.
  formula would overstate their error by orders of magnitude.

Variance, std and quantiles of the output are the pooled sample estimates for every rule.

With ``control`` (``"taylor-local"`` or ``"taylor"``) a few control realizations open the
design and give a quadratic surrogate whose mean is known; mean, variance and their errors are
then the control-variate estimates of ``uqflow/methods/control_variate.py`` (quantiles stay
the plain sample ones). See docs/control_variates.md.

With ``[[limit_states]]`` (``uqflow.limit_states``) the statistics add, per limit state, the
failure count among the realizations that ran ok, P[failure], its interval, its coefficient
of variation and the reliability index (``uqflow.probability``). A realization that did not run
ok is neither a failure nor safe: it is counted apart and left out. The interval follows the
rule:

* ``random``: Clopper–Pearson (exact binomial; coverage at least the level for every p, n).
* ``lhs``: Clopper–Pearson too. The failures of a Latin hypercube are not binomial, but the
  variance of its fraction is at most N / (N - 1) times the binomial one for any N (Owen 1997)
  and asymptotically never above it (Stein 1987), so the binomial interval is conservative
  up to that factor, as the mean's i.i.d. error is.
* ``sobol``/``halton``: the mean of the replicates' failure fractions, a Student t interval
  over their spread (R - 1 degrees of freedom), the c.o.v. their standard error / P.

``interval = "wilson"`` replaces Clopper–Pearson for independent points (refused for
randomized QMC). Each limit state's whole exceedance curve is stored too (P[Y >= y] of its
reduced output for ``exceeds``, P[Y <= y] for ``below``, a system's margin G as P[G <= y]),
at the distinct values thinned to at most ``uqflow.probability.MAX_CURVE_LEVELS`` and the
threshold, with the same interval at every level (a pointwise band); the report draws it on
a log axis (``uqflow.report.framework_figures.exceedance_log_figure``).

``target_cov`` stops, at the same ``stop_points`` as ``target_rel_stderr``, once every limit
state's c.o.v. is at most the target (both targets must hold when both are set).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import warnings as pywarnings

import numpy as np
import xarray as xr
from pydantic import Field, ValidationInfo, field_validator, model_validator
from scipy import stats as sps

from uqflow import probability
from uqflow.errors import AccuracyWarning, StudyError
from uqflow.limit_states import EXCEEDS, LimitState, LimitStates

from uqflow.methods import control_variate as cv
from uqflow.layout import (BOUND, BOUND_HIGH, BOUND_LOW, CONFIDENCE, EXCEEDANCE_COMPARISON,
                           EXCEEDANCE_INTERVAL, EXCEEDANCE_LEVEL, EXCEEDANCE_NOTE,
                           EXCEEDANCE_POINT, EXCEEDANCE_PROBABILITY, EXCEEDANCE_QUANTITY,
                           EXCEEDANCE_THRESHOLD, EXCEEDANCE_UNITS, FAILURE_COV,
                           FAILURE_INTERVAL, FAILURE_LEFT_OUT, FAILURE_NOTE,
                           FAILURE_PROBABILITY, FAILURE_RUNS, FAILURES, INTERVAL_METHOD,
                           LIMIT_STATE, REALIZATION, RELIABILITY_INDEX, SOLVER_RUNS, STATISTIC,
                           STATISTIC_CI_HIGH, STATISTIC_CI_LOW, STATISTIC_MEAN, STATISTIC_STD,
                           STATISTIC_STDERR, STATISTIC_VARIANCE, STATUS, STATUS_PENDING)
from uqflow.methods.base import (MethodOptions, PropagationMethod, failure_warning,
                                 finish_statistics, make_design, ok_mask, output_names,
                                 register_method)
from uqflow.report import (Column, FigureSpec, MethodReport, axis_label, exceedance_log_figure,
                           new_figure, number, scientific_ticks)
from uqflow.sampling import QUASI_RANDOM_RULES, replicated_unit_hypercube, unit_hypercube

#: ``stderr_kind`` of the statistics, per rule: which formula the standard error uses.
STDERR_KINDS = {"random": "iid", "lhs": "iid-conservative", "sobol": "rqmc", "halton": "rqmc"}
#: each rule's points in words, for a legend
RULE_WORDS = {"random": "independent random points", "lhs": "Latin hypercube",
              "sobol": "scrambled Sobol' points", "halton": "scrambled Halton points"}


class SampleStatisticsOptions(MethodOptions):
    """What every sampling method estimates and when it may stop (shared by kl-weibull)."""

    quantiles: list[float] = Field(default_factory=lambda: [0.05, 0.5, 0.95])
    confidence: float = Field(0.95, gt=0, lt=1, description="level of the mean's interval")
    target_rel_stderr: float | None = Field(
        None, gt=0, description="stop once stderr/|mean| of every output is below this")
    target_cov: float | None = Field(
        None, gt=0, description="stop once the estimated coefficient of variation of every "
                                "limit state's P[failure] is at most this ([[limit_states]])")
    min_samples: int = Field(32, ge=2, description="never stop on target before this many")
    trace_points: int = Field(25, ge=2, description="sample counts in the convergence trace")

    @field_validator("quantiles")
    @classmethod
    def _quantiles_in_unit_interval(cls, q):
        if any(not 0 <= x <= 1 for x in q):
            raise ValueError("every quantile must lie in [0, 1]")
        return sorted(set(q))


class MonteCarloOptions(SampleStatisticsOptions):
    # rule and replicates come before samples: the samples check reads them.
    rule: Literal["random", "lhs", "sobol", "halton"] = "random"
    # 8, from the expected half-width of the t interval, t(R-1) c4(R) sigma_R / sqrt(R), with
    # sigma_R the std of one replicate's mean on n/R points, ~ (n/R)^-alpha: for smooth outputs
    # (alpha = 3/2, scrambled Sobol') it grows like R, for rough ones (alpha = 1/2) it falls
    # to 1.96. R = 8 is within 16 % of the best for rough outputs (2.28); R = 4 would be
    # narrower for smooth ones but leaves 3 degrees of freedom (the error estimate's own
    # spread ~ 1/sqrt(2 dof) = 41 %, against 27 % at R = 8). A power of two, so 2^k samples
    # split into balanced Sobol' prefixes. docs/inputs.md has the table.
    replicates: int = Field(8, ge=2, le=4096, description="independent scramblings of a "
                            "quasi-random rule (sobol, halton); their spread is the error")
    samples: int = Field(1000, ge=1, description="number of realizations (the most run)")
    control: Literal["none", "taylor-local", "taylor"] = Field(
        "none", description="control variate: the second-order Taylor surrogate from the "
                            "solver's local derivatives (1 extra run) or from central "
                            "differences (2n+1 extra runs)")
    # at most taylor.MAX_STEP (a std): Taylor refuses a wider stencil
    control_step: float = Field(0.1, gt=0, le=1.0, description="control = \"taylor\": the "
                                "stencil step as a fraction of each input's std")
    interval: Literal["clopper-pearson", "wilson"] = Field(
        "clopper-pearson", description="interval of P[failure] and of each level of the "
        "exceedance curve for independent points (random, lhs) ([[limit_states]])")

    @field_validator("samples")
    @classmethod
    def _whole_replicates(cls, samples, info: ValidationInfo):
        rule, r = info.data.get("rule"), info.data.get("replicates")
        if rule not in QUASI_RANDOM_RULES or r is None:
            return samples
        if rule == "sobol":
            m = samples // r
            if samples % r or m & (m - 1):
                below = r * 2 ** max(int(np.floor(np.log2(max(samples / r, 1)))), 0)
                near = sorted({below, 2 * below} - {samples})
                raise ValueError(
                    f"{samples} is not replicates ({r}) times a power of two, which rule "
                    f"'sobol' needs for balanced replicates; nearest: "
                    f"{' or '.join(map(str, near))}")
        elif samples % r:
            below = samples // r * r
            near = [c for c in (below, below + r) if c >= r]
            raise ValueError(f"{samples} is not a multiple of replicates ({r}), which rule "
                             f"'halton' needs; nearest: {' or '.join(map(str, near))}")
        return samples

    @model_validator(mode="after")
    def _replicates_only_for_quasi_random(self):
        return self.only_where("replicates", self.rule in QUASI_RANDOM_RULES,
                               f"rule sobol or halton only; rule '{self.rule}' has "
                               f"independent points")

    @model_validator(mode="after")
    def _interval_only_for_independent_points(self):
        return self.only_where("interval", self.rule not in QUASI_RANDOM_RULES,
                               f"independent points (rule random or lhs); rule '{self.rule}' "
                               f"is randomized QMC, whose interval is the spread of its "
                               f"replicates")

    @model_validator(mode="after")
    def _control_step_only_for_taylor(self):
        return self.only_where("control_step", self.control == "taylor",
                               f'control = "taylor" only, not "{self.control}"')


@register_method("monte-carlo")
class MonteCarlo(PropagationMethod):
    """Monte Carlo sampling (random, LHS, scrambled Sobol or Halton) with error estimates."""

    Options = MonteCarloOptions
    uses_limit_states = True

    @property
    def control(self) -> str:
        """The control variate ("none" also for subclasses whose options have no control)."""
        return getattr(self.options, "control", "none")

    def check(self, space, fields):
        super().check(space, fields)
        if self.control != "none":
            cv.check_space(self.control, self.options.control_step, space)

    def check_solver(self, solver, outputs, parameter_names):
        cv.check_solver(self.control, solver, outputs, parameter_names)

    def check_limit_states(self, limit_states):
        super().check_limit_states(limit_states)
        self._check_target_cov()

    def _check_target_cov(self):
        if self.limit_states is None and getattr(self.options, "target_cov", None) is not None:
            raise StudyError("target_cov is a target for P[failure] of the limit states, and "
                             "the study has no [[limit_states]]: add them, or drop the key",
                             key="method.target_cov")
        if self.limit_states is None and "interval" in self.options.model_fields_set:
            raise StudyError("interval is the interval of P[failure] of the limit states, and "
                             "the study has no [[limit_states]]: add them, or drop the key",
                             key="method.interval")

    @property
    def interval(self) -> str:
        """The binomial interval of P[failure] for independent points (kl-weibull, which has
        no ``interval`` option, Clopper-Pearson)."""
        return getattr(self.options, "interval", probability.CLOPPER_PEARSON)

    def plan(self, space, fields, seed):
        self.check(space, fields)
        self._check_target_cov()
        rule, n = self.options.rule, self.options.samples
        if rule in QUASI_RANDOM_RULES:
            r = self.options.replicates
            u = replicated_unit_hypercube(rule, r, n // r, len(space), seed)
        else:
            u = unit_hypercube(rule, n, len(space), seed)
        design = make_design(space, space.from_unit_hypercube(u))
        design.attrs["rule"] = rule
        if rule in QUASI_RANDOM_RULES:
            design.attrs["replicates"] = self.options.replicates
        if self.control != "none":
            design = cv.with_control(self.control, self.options.control_step, space,
                                     design)
        return design

    def _replicates(self, design) -> int | None:
        """R of a randomized-QMC design, None for independent points."""
        if design.attrs.get("rule", self.options.rule) not in QUASI_RANDOM_RULES:
            return None
        return int(design.attrs.get("replicates", getattr(self.options, "replicates", 0)))

    def _targets(self) -> bool:
        return self.options.target_rel_stderr is not None or \
            getattr(self.options, "target_cov", None) is not None

    def stop_points(self, n_planned):
        if not self._targets():
            return np.zeros(0, dtype=np.int64)
        # The control realizations open the design; the counts are over the samples after
        # them, so a study stops at the same samples with and without a control.
        control = max(n_planned - self.options.samples, 0) if self.control != "none" else 0
        n_samples = n_planned - control
        if self.options.rule in QUASI_RANDOM_RULES:
            # Only whole balanced prefixes of every replicate: R 2^k realizations.
            r = self.options.replicates
            counts = r * 2 ** np.arange(int(np.log2(max(n_samples // r, 1))) + 1)
            counts = counts[(counts >= self.options.min_samples) & (counts <= n_samples)]
            return counts.astype(np.int64) + control
        # Checks about 9 % apart: the overshoot past the first sufficient count stays below
        # that, and the number of checks grows only with log(n).
        first = min(self.options.min_samples, n_samples)
        k_max = int(np.ceil(8 * np.log2(max(n_samples / max(first, 1), 1.0))))
        counts = np.ceil(first * 2.0 ** (np.arange(k_max + 1) / 8)).astype(np.int64)
        return np.unique(np.minimum(counts, n_samples)) + control

    def enough(self, design, runs):
        if not self._targets():
            return False
        target = self.options.target_rel_stderr
        r = self._replicates(design)
        _, samples = cv.sample_part(design, runs)
        count = samples.sizes[REALIZATION]
        if r is not None:
            # Judge the longest prefix of whole replicate prefixes with nothing pending.
            pending = np.flatnonzero(samples[STATUS].values == STATUS_PENDING)
            finished = int(pending[0]) if pending.size else count
            count = finished // r * r
        ok = ok_mask(samples)[:count]
        if ok.sum() < self.options.min_samples:
            return False
        target_cov = getattr(self.options, "target_cov", None)
        if target_cov is not None:
            prefix = samples.isel({REALIZATION: slice(0, count)})
            covs = [e.cov for e in failure_estimates(self.limit_states, prefix, r,
                                                     self.options.confidence, self.interval)]
            # NaN (no estimate of the error yet) is not below any target
            if not all(c <= target_cov for c in covs):
                return False
        if target is None:
            return True
        surrogates = self._surrogates(design, runs, quiet=True)
        for out in output_names(runs):
            if surrogates:
                est = cv.sample_estimates(surrogates[out], design, runs, out,
                                          r or cv.CROSS_FIT_FOLDS, r is not None, count)
                shape = runs[out].shape[1:]
                mean, stderr = est.mean.reshape(shape), est.stderr.reshape(shape)
            else:
                mean, stderr, _, _ = _mean_error(samples[out].values[:count], ok, r)
            # A field output is judged against its largest |mean|: elements crossing zero
            # would otherwise never reach any relative target.
            scale = np.maximum(np.abs(mean), np.max(np.abs(mean)))
            with np.errstate(divide="ignore", invalid="ignore"):
                rel = np.where(stderr == 0, 0.0, stderr / scale)
            if not np.all(rel <= target):
                return False
        return True

    def _surrogates(self, design, runs, quiet=False, warnings=None):
        """The control's surrogates, or None (no control, or it failed: then plain MC)."""
        if not cv.control_count(design):
            return None
        try:
            return cv.build_surrogates(design, runs)
        except cv.ControlFailed as err:
            if not quiet:
                msg = (f"control \"{design.attrs['control']}\" gave no surrogate ({err}): the "
                       f"statistics are plain Monte Carlo over the samples")
                warnings.append(msg)
                pywarnings.warn(msg, AccuracyWarning, stacklevel=3)
            return None

    def analyze(self, design, runs):
        opts = self.options
        rule = design.attrs.get("rule", opts.rule)
        r = self._replicates(design)
        warnings = failure_warning(runs)
        surrogates = self._surrogates(design, runs, warnings=warnings)
        _, samples = cv.sample_part(design, runs)
        ok = ok_mask(samples)
        n = int(ok.sum())
        q_labels = [f"q{100 * q:g}" for q in opts.quantiles]
        labels = [STATISTIC_MEAN, STATISTIC_VARIANCE, STATISTIC_STD, STATISTIC_STDERR,
                  STATISTIC_CI_LOW, STATISTIC_CI_HIGH, *q_labels]
        data, dof = {}, n - 1
        for out in output_names(runs):
            y = samples[out].values[ok]
            dims = runs[out].dims[1:]
            if n == 0:
                block = np.full((len(labels),) + runs[out].shape[1:], np.nan)
            else:
                plain = _mean_error(samples[out].values, ok, r)
                mean, stderr, dof, replicate_means = plain
                _, var = _mean_var(y)
                if surrogates:
                    plain_var = var
                    est = cv.sample_estimates(surrogates[out], design, runs, out,
                                              r or cv.CROSS_FIT_FOLDS, r is not None)
                    shape = runs[out].shape[1:]
                    mean, stderr, var = (a.reshape(shape)
                                         for a in (est.mean, est.stderr, est.variance))
                    dof = est.dof
                    replicate_means = est.fold_means.reshape((-1, *shape))
                    data.update(cv.control_variables(out, runs, dims, est, n, shape,
                                                   (plain[0], plain_var, plain[1]),
                                                   surrogates[out]))
                t = sps.t.ppf(0.5 + opts.confidence / 2, dof) if dof > 0 else np.nan
                quant = np.quantile(y, opts.quantiles, axis=0)
                block = np.stack([mean, var, np.sqrt(np.maximum(var, 0.0)), stderr,
                                  mean - t * stderr, mean + t * stderr, *quant])
                if r is not None:
                    what = ("control-variate estimate of the mean of {out} from each scrambled "
                            "replicate (its slope from the other replicates)" if surrogates
                            else "mean of {out} over each scrambled replicate")
                    data[f"{out}_replicate_means"] = (
                        ("replicate", *dims), replicate_means,
                        {"long_name": what.format(out=out) + " (NaN: no successful "
                                                             "realization in it)"})
            data[out] = ((STATISTIC, *dims), block)
            if surrogates:
                data[f"{out}_trace"], counts = cv.control_trace(
                    surrogates[out], design, runs, out, dims, r, opts.trace_points)
            elif r is None:
                data[f"{out}_trace"], counts = self._trace(y, dims)
            else:
                data[f"{out}_trace"], counts = _rqmc_trace(samples[out].values, ok, r, dims)
        coords = {STATISTIC: labels, "trace_statistic": ["mean", "std", "stderr"]}
        if data:
            coords["trace_samples"] = counts
        if surrogates:
            coords.update(plain_statistic=["mean", "variance", "stderr"],
                          surrogate_statistic=["mean", "variance"])
        if self.limit_states is not None:
            estimates = failure_estimates(self.limit_states, samples, r, opts.confidence,
                                          self.interval)
            data.update(failure_variables(estimates))
            data.update(exceedance_variables(self.limit_states, samples, r, opts.confidence,
                                             self.interval))
            coords.update({LIMIT_STATE: list(self.limit_states.names),
                           BOUND: [BOUND_LOW, BOUND_HIGH]})
            warnings.extend(e.warning for e in estimates if e.warning)
        stats = xr.Dataset(data, coords=coords)
        stats = stats.assign_coords({d: runs[d] for d in runs.coords
                                     if d not in (REALIZATION,) and d in stats.dims})
        if n < 2:
            warnings.append(f"only {n} realization(s) succeeded: no variance can be estimated")
        stats = finish_statistics(stats, design, runs, self.name, warnings)
        stats.attrs.update(rule=rule, samples_ok=n, confidence=opts.confidence,
                           stderr_kind=STDERR_KINDS[rule], degrees_of_freedom=int(max(dof, 0)),
                           stderr_note=_stderr_note(rule, r, dof, surrogates is not None))
        if r is not None:
            stats.attrs["replicates"] = r
        if cv.control_count(design):
            stats.attrs.update(cv.control_attrs(design, samples, surrogates is not None))
        if self.limit_states is not None:
            stats.attrs.update({
                INTERVAL_METHOD: self.interval if r is None else probability.REPLICATE_T,
                FAILURE_NOTE: _failure_note(rule, r, estimates, opts.confidence,
                                            self.interval),
                EXCEEDANCE_NOTE: _exceedance_note(r, opts.confidence, self.interval)})
        return stats

    @classmethod
    def report(cls, view):
        """The interval of the mean, which error it rests on, what a control variate bought,
        the rule, and each output's convergence; the runs are draws (a control variate's
        control runs are left out by ``uqflow.layout.sample_mask``)."""
        stats = view.stats
        rule = stats.attrs.get("rule")
        return MethodReport(
            description=_description(stats),
            runs_are_draws=True,
            columns=[_interval_column(stats)] if STATISTIC_CI_LOW in stats[STATISTIC].values
            else [],
            notes=sample_notes(view) + failure_lines(stats)
            + cv.report_lines(stats, view.outputs, view.focus, view.where),
            cost_details=[f"rule {rule}"] if rule else [],
            figures=[FigureSpec("convergence", convergence_figure)]
            + failure_exceedance_figures(stats))

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


@dataclass(frozen=True)
class FailureEstimate:
    """P[failure] of one limit state from the realizations of a Monte Carlo design.

    ``failures`` among ``runs`` realizations that ran ok; ``left_out`` did not (neither
    failure nor safe). ``warning`` says why the interval is NaN, if it is."""

    failures: int
    runs: int
    left_out: int
    probability: float
    interval: probability.ProbabilityInterval
    cov: float
    warning: str = ""


def failure_estimates(limit_states, samples, replicates, confidence,
                      interval=probability.CLOPPER_PEARSON) -> list[FailureEstimate]:
    """Each limit state's estimate from ``samples`` (the draws of the design: realizations in
    design order, a control variate's control runs left out). Independent points
    (``replicates`` None): k / n, the binomial ``interval`` (Clopper-Pearson or Wilson),
    c.o.v. sqrt((1 - p) / (n p)). Randomized
    QMC: realization i is in replicate i mod R; the mean of the replicates' fractions, a t
    interval over their spread, c.o.v. their standard error / p."""
    ok = ok_mask(samples)
    margins = limit_states.margins(samples).transpose(REALIZATION, LIMIT_STATE).values
    failed = np.asarray(limit_states.failures(samples).transpose(REALIZATION, LIMIT_STATE)
                        .values, dtype=bool)
    # A realization that did not run ok counts as neither failure nor safe, whatever a
    # margin computed from its (NaN) outputs says.
    judged = ok[:, None] & np.isfinite(margins)
    failed &= judged
    replicate = np.arange(ok.size) % replicates if replicates else None
    found = []
    for j, name in enumerate(limit_states.names):
        k, n = int(failed[:, j].sum()), int(judged[:, j].sum())
        if replicates is None:
            bounds = probability.binomial_interval(k, n, interval, confidence)
            p = k / n if n else np.nan
            cov = probability.binomial_cov(p, n)
        else:
            fractions = [failed[judged[:, j] & (replicate == q), j].mean()
                         if np.any(judged[:, j] & (replicate == q)) else np.nan
                         for q in range(replicates)]
            p, stderr, bounds = probability.replicate_interval(fractions, confidence)
            cov = stderr / p if p > 0 and not bounds.reason else \
                (np.inf if p == 0 else np.nan)
        warning = f"limit state '{name}': no interval of P[failure]: {bounds.reason}" \
            if bounds.reason else ""
        found.append(FailureEstimate(k, n, ok.size - n, float(p), bounds, float(cov),
                                     warning))
    return found


def failure_variables(estimates: list[FailureEstimate]) -> dict:
    """The statistics variables (dim ``limit_state``) of the estimates."""
    def column(values, what, dtype=float):
        return (LIMIT_STATE,), np.array(values, dtype=dtype), {"long_name": what}

    p = np.array([e.probability for e in estimates])
    return {
        FAILURES: column([e.failures for e in estimates], "failure events among the "
                         "realizations that ran ok", np.int64),
        FAILURE_RUNS: column([e.runs for e in estimates], "realizations that ran ok, over "
                             "which P[failure] is estimated", np.int64),
        FAILURE_LEFT_OUT: column([e.left_out for e in estimates], "realizations that did not "
                                 "run ok: neither failure nor safe, left out", np.int64),
        FAILURE_PROBABILITY: column(p, "estimated probability of failure"),
        FAILURE_INTERVAL: ((LIMIT_STATE, BOUND),
                           np.array([[e.interval.low, e.interval.high] for e in estimates],
                                    dtype=float).reshape(-1, 2),
                           {"long_name": "interval of the probability of failure"}),
        FAILURE_COV: column([e.cov for e in estimates], "coefficient of variation of the "
                            "estimate of P[failure]"),
        RELIABILITY_INDEX: column(probability.reliability_index(p),
                                  "reliability index -Phi^-1(P[failure])"),
    }


def exceedance_variables(limit_states, samples, replicates, confidence,
                         interval=probability.CLOPPER_PEARSON) -> dict:
    """Each limit state's exceedance curve from ``samples`` (as ``failure_estimates``): the
    statistics variables (limit_state, exceedance_point), NaN-padded.

    A limit state on an output: Y its reduced output (what the threshold is compared with),
    P[Y >= y] for ``exceeds`` and P[Y <= y] for ``below`` (the failure event with threshold y:
    at the threshold, P[failure] and its interval exactly; for a continuous Y the same as
    P[Y > y] and P[Y < y]). A system, or a limit state known only by its margins: Y its
    margin g, P[G <= y], threshold 0. Independent points: the fraction and the binomial
    ``interval`` at each level; randomized QMC: the mean of the replicates' fractions and
    the t interval over their spread at each level."""
    ok = ok_mask(samples)
    margins = limit_states.margins(samples).transpose(REALIZATION, LIMIT_STATE)
    replicate = np.arange(ok.size) % replicates if replicates else None
    curves, quantities, comparisons, thresholds, units = [], [], [], [], []
    for name in limit_states.names:
        state = limit_states[name] if isinstance(limit_states, LimitStates) else None
        if isinstance(state, LimitState):
            y = np.asarray(state.reduce.apply(samples[state.output], state.comparison)
                           .values, dtype=float)
            comparison = probability.AT_OR_ABOVE if state.comparison == EXCEEDS \
                else probability.AT_OR_BELOW
            quantity, threshold, unit = (state.reduce.describe(state.output),
                                         state.threshold, state.units)
        else:
            y = np.asarray(margins.sel({LIMIT_STATE: name}).values, dtype=float)
            comparison, threshold, unit = probability.AT_OR_BELOW, 0.0, ""
            quantity = f"margin g of {name}" + (f" ({state.describe()})" if state else "")
        # a realization that did not run ok, or has no margin (an outcome neither 0 nor 1),
        # is left out, as from P[failure]
        judged = ok & np.isfinite(np.asarray(margins.sel({LIMIT_STATE: name}).values, float))
        y = np.where(judged, y, np.nan)
        curves.append(probability.exceedance_curve(y, threshold, comparison, interval,
                                                   confidence, replicate, replicates))
        quantities.append(quantity)
        comparisons.append(comparison)
        thresholds.append(threshold)
        units.append(unit)
    size = max((c.levels.size for c in curves), default=0)

    def padded(arrays):
        block = np.full((len(arrays), size), np.nan)
        for j, a in enumerate(arrays):
            block[j, :a.size] = a
        return block

    band = np.stack([padded([c.low for c in curves]), padded([c.high for c in curves])],
                    axis=-1)
    per_state = (LIMIT_STATE,)
    return {
        EXCEEDANCE_LEVEL: ((LIMIT_STATE, EXCEEDANCE_POINT), padded([c.levels for c in curves]),
                           {"long_name": "levels y of the exceedance curve (NaN: padding)"}),
        EXCEEDANCE_PROBABILITY: ((LIMIT_STATE, EXCEEDANCE_POINT),
                                 padded([c.probability for c in curves]),
                                 {"long_name": "P[Y >= y] (exceeds) or P[Y <= y] (below)"}),
        EXCEEDANCE_INTERVAL: ((LIMIT_STATE, EXCEEDANCE_POINT, BOUND), band,
                              {"long_name": "pointwise interval of the exceedance curve"}),
        EXCEEDANCE_QUANTITY: (per_state, np.array(quantities, dtype=object),
                              {"long_name": "the quantity Y of the exceedance curve"}),
        EXCEEDANCE_COMPARISON: (per_state, np.array(comparisons, dtype=object),
                                {"long_name": "the curve is P[Y >= y] or P[Y <= y]"}),
        EXCEEDANCE_THRESHOLD: (per_state, np.array(thresholds, dtype=float),
                               {"long_name": "the limit state's threshold on Y"}),
        EXCEEDANCE_UNITS: (per_state, np.array(units, dtype=object),
                           {"long_name": "units of Y and of the levels"}),
    }


def _exceedance_note(replicates, confidence, interval) -> str:
    level = f"{100 * confidence:g} %"
    if replicates is not None:
        how = (f"mean of the {replicates} replicates' fractions at or beyond each level, "
               f"{level} Student t interval over their spread at each level")
    else:
        name = "Clopper-Pearson" if interval == probability.CLOPPER_PEARSON else "Wilson"
        how = (f"fraction of the realizations that ran ok at or beyond each level, {level} "
               f"{name} interval at each level")
    return (f"{how}: a pointwise band (each level covers at its level; the curve as a whole "
            f"less); levels: the distinct values, at most {probability.MAX_CURVE_LEVELS} "
            f"(every value of the tail, fewer towards P = 1), and the threshold")


def _failure_note(rule, replicates, estimates, confidence,
                  interval=probability.CLOPPER_PEARSON) -> str:
    """How P[failure] and its interval were estimated, and what was left out, in words."""
    level = f"{100 * confidence:g} %"
    if replicates is not None:
        how = (f"mean of the failure fractions of {replicates} independently scrambled {rule} "
               f"replicates; {level} Student t interval over their spread; c.o.v. = their "
               f"standard error / P")
    else:
        name = "Clopper-Pearson (exact binomial)" if interval == probability.CLOPPER_PEARSON \
            else "Wilson score (shorter; its coverage dips below the level for small n P)"
        how = (f"failures / realizations that ran ok; {level} {name} interval; c.o.v. = "
               f"sqrt((1 - P) / (n P))")
        if rule == "lhs":
            how += ("; Latin hypercube points are not independent: the binomial interval is "
                    "conservative up to N/(N-1) in variance (Owen 1997)")
    left_out = max((e.left_out for e in estimates), default=0)
    if left_out:
        how += (f"; {left_out} realization(s) did not run ok and are left out, counted neither "
                f"as failures nor as safe (P[failure] is biased if solver errors depend on "
                f"the inputs)")
    return how


def failure_lines(stats) -> list[str]:
    """One report line per limit state: P[failure], its interval, c.o.v., beta, counts."""
    if FAILURE_PROBABILITY not in stats:
        return []
    level = f"{100 * float(stats.attrs.get(CONFIDENCE, 0.95)):g} %"
    lines = []
    for name in stats[LIMIT_STATE].values:
        at = {LIMIT_STATE: name}
        low, high = (float(stats[FAILURE_INTERVAL].sel(at).sel({BOUND: b}))
                     for b in (BOUND_LOW, BOUND_HIGH))
        left_out = int(stats[FAILURE_LEFT_OUT].sel(at))
        lines.append(
            f"P[failure of {name}] = {number(float(stats[FAILURE_PROBABILITY].sel(at)))} "
            f"({level} interval {number(low)} .. {number(high)}), c.o.v. "
            f"{number(float(stats[FAILURE_COV].sel(at)))}, beta = "
            f"{number(float(stats[RELIABILITY_INDEX].sel(at)))}; "
            f"{int(stats[FAILURES].sel(at))} failures in {int(stats[FAILURE_RUNS].sel(at))} "
            f"runs" + (f", {left_out} not run ok and left out" if left_out else ""))
    note = stats.attrs.get(FAILURE_NOTE)
    if note:
        lines.append(f"P[failure]: {note}")
    return lines


def failure_exceedance_figures(stats) -> list[FigureSpec]:
    """A figure per limit state of the result: its stored exceedance curve on a log axis,
    with its band, the threshold and P[failure] (``exceedance_log_figure``); saved as
    ``failure_exceedance_<limit state>.png``. None without stored curves."""
    if EXCEEDANCE_PROBABILITY not in stats:
        return []
    return [FigureSpec(f"failure_exceedance_{name}",
                       lambda view, _, name=str(name): exceedance_figure_of(view.stats, name,
                                                                           view.study),
                       per_output=False)
            for name in stats[LIMIT_STATE].values]


def exceedance_figure_of(stats, name: str, study: str = ""):
    """The exceedance figure of limit state ``name`` from the statistics."""
    at = stats.sel({LIMIT_STATE: name})
    levels = np.asarray(at[EXCEEDANCE_LEVEL].values, dtype=float)
    keep = np.isfinite(levels)
    band = np.asarray(at[EXCEEDANCE_INTERVAL].values, dtype=float)[keep]
    comparison = str(at[EXCEEDANCE_COMPARISON].values)
    pf_low, pf_high = np.asarray(at[FAILURE_INTERVAL].values, dtype=float)
    how = {probability.CLOPPER_PEARSON: "Clopper-Pearson", probability.WILSON: "Wilson",
           probability.REPLICATE_T: "Student t over the replicates"}.get(
        str(stats.attrs.get(INTERVAL_METHOD, "")), "as stated in exceedance_note")
    level = f"{100 * float(stats.attrs.get(CONFIDENCE, 0.95)):g} %"
    runs = int(at[FAILURE_RUNS].values)
    quantity = str(at[EXCEEDANCE_QUANTITY].values)
    return exceedance_log_figure(
        levels[keep], np.asarray(at[EXCEEDANCE_PROBABILITY].values, dtype=float)[keep],
        band[:, 0], band[:, 1], threshold=float(at[EXCEEDANCE_THRESHOLD].values),
        failure_probability=float(at[FAILURE_PROBABILITY].values),
        failure_interval=(pf_low, pf_high), comparison=comparison, name=quantity,
        units=str(at[EXCEEDANCE_UNITS].values),
        curve_label=f"fraction of {runs} runs at or {'above' if comparison == '>=' else 'below'} y",
        band_label=f"{level} pointwise band ({how})",
        title=f"{study + ': ' if study else ''}limit state '{name}'\n"
              f"exceedance of {quantity} (Monte Carlo)")


def _description(stats) -> str:
    """'Monte Carlo, 8 runs (scrambled Sobol' points), one-run Taylor as control variate'."""
    samples = int(stats.attrs.get(SOLVER_RUNS, 0)) - int(stats.attrs.get("control_runs", 0))
    rule = RULE_WORDS.get(str(stats.attrs.get("rule", "")))
    text = f"Monte Carlo, {samples} run{'' if samples == 1 else 's'}" + \
        (f" ({rule})" if rule else "")
    control = cv.described(stats)
    return f"{text}, {control}" if control else text


def _interval_column(stats) -> Column:
    level = float(stats.attrs.get(CONFIDENCE, 0.95))

    def interval(out, focus):
        at = stats[out].isel(focus)
        return (f"{number(at.sel({STATISTIC: STATISTIC_CI_LOW}))} .. "
                f"{number(at.sel({STATISTIC: STATISTIC_CI_HIGH}))}")

    return Column(f"{100 * level:g} % CI of the mean [u]", interval)


def sample_notes(view) -> list[str]:
    """Which error the interval of the mean rests on: it decides how far it can be trusted."""
    note = view.stats.attrs.get("stderr_note")
    return [f"standard error and interval of the mean: {note}"] if note else []


def convergence_figure(view, out: str):
    """The running mean with its interval, and the running std, against the sample count at
    the output's row point (None without a trace of at least two counts)."""
    stats = view.stats
    if f"{out}_trace" not in stats:
        return None
    counts = np.asarray(stats["trace_samples"].values, float)
    if counts.size < 2:
        return None
    focus = view.focus(out)
    trace = stats[f"{out}_trace"].isel(focus)
    mean, std, stderr = (np.asarray(trace.sel(trace_statistic=s).values, float)
                         for s in ("mean", "std", "stderr"))
    units = view.units(out)
    fig, (ax, ax2) = new_figure(height=5.2, rows=2)
    level = float(stats.attrs.get(CONFIDENCE, 0.95))
    replicates = stats.attrs.get("replicates")
    if stats.attrs.get("stderr_kind") == "rqmc" and replicates:
        # The band is the interval the table reports: t with R - 1 degrees of freedom.
        half = sps.t.ppf(0.5 + level / 2, int(replicates) - 1) * stderr
        label = (f"{100 * level:g} % interval, randomized QMC ({int(replicates)} replicates, "
                 f"t with {int(replicates) - 1} dof)")
    else:
        half, label = 1.96 * stderr, "± 1.96 stderr"
    ax.fill_between(counts, mean - half, mean + half, color="#9ab7d3", alpha=0.6, linewidth=0,
                    label=label)
    ax.plot(counts, mean, color="#1f4e79", marker="o", markersize=3, label="running mean")
    ax.axhline(mean[-1], color="#c0392b", linestyle="--", linewidth=1,
               label=f"final mean {mean[-1]:.4g}")
    ax.set_ylabel(axis_label(f"mean of {out}", units))
    scientific_ticks(ax, "y")
    ax.legend(loc="best", fontsize="small")
    ax2.plot(counts, std, color="#2e7d32", marker="o", markersize=3, label="running std")
    ax2.set_ylabel(axis_label(f"std of {out}", units))
    scientific_ticks(ax2, "y")
    ax2.set_xlabel("number of samples")
    ax2.set_xscale("log")
    ax.set_title(view.title(out, "Monte Carlo convergence", focus))
    return fig


def _stderr_note(rule: str, replicates: int | None, dof: int, control: bool = False) -> str:
    """One line saying which error estimate the standard error and the interval use."""
    if control:
        if replicates is not None:
            return (f"control variate, randomized QMC: spread of the control-variate means of "
                    f"{replicates} independently scrambled {rule} replicates, Student t with "
                    f"{dof} degrees of freedom")
        return (f"control variate: sqrt((1 - rho^2) s^2 / n), Student t with {dof} degrees "
                f"of freedom" + (" (conservative for Latin hypercube)" if rule == "lhs"
                                 else ""))
    if replicates is not None:
        return (f"randomized QMC: spread of the means of {replicates} independently scrambled "
                f"{rule} replicates, Student t with {dof} degrees of freedom")
    if rule == "lhs":
        return (f"i.i.d. formula, conservative for Latin hypercube (its variance is at most "
                f"N/(N-1) times the i.i.d. one, Owen 1997), Student t with {dof} degrees of "
                f"freedom")
    return f"i.i.d. formula s/sqrt(n), Student t with {dof} degrees of freedom"


def _mean_error(values, ok, replicates):
    """Mean, its standard error, the degrees of freedom of that error, replicate means.

    ``values`` are all realizations (realization first), ``ok`` which succeeded. Independent
    points (``replicates`` None): the sample mean and s / sqrt(n), n - 1 degrees of freedom.
    Randomized QMC: realization i belongs to replicate i mod R; the mean is the mean of the
    replicate means, the error their spread / sqrt(R'), R' - 1 degrees of freedom, where R'
    counts the replicates with at least one successful realization. ``enough``, ``analyze``
    and the trace all go through here, so they cannot disagree.
    """
    y = values[ok]
    if replicates is None:
        mean, var = _mean_var(y)
        return mean, np.sqrt(var / y.shape[0]), y.shape[0] - 1, None
    which = np.flatnonzero(ok) % replicates
    present = np.array([np.any(which == r) for r in range(replicates)])
    replicate_means = np.full((replicates,) + y.shape[1:], np.nan)
    for r in np.flatnonzero(present):
        # _mean_var keeps an output that is equal on every point exact (no rounding noise).
        replicate_means[r] = _mean_var(y[which == r])[0]
    mean, var = _mean_var(replicate_means[present])
    count = int(present.sum())
    return mean, np.sqrt(var / max(count, 1)), count - 1, replicate_means


def _rqmc_trace(values, ok, replicates, dims):
    """Running mean, pooled std and RQMC standard error after R 2^k realizations (whole,
    balanced prefixes of every replicate) and after all of them."""
    n = values.shape[0]
    counts = replicates * 2 ** np.arange(int(np.log2(max(n // replicates, 1))) + 1)
    counts = np.unique(np.append(counts[counts <= n], n // replicates * replicates))
    counts = counts[counts > 0]
    rows = []
    for c in counts:
        mask = ok[:c]
        if mask.sum() == 0:
            rows.append(np.full((3,) + values.shape[1:], np.nan))
            continue
        mean, stderr, _, _ = _mean_error(values[:c], mask, replicates)
        _, var = _mean_var(values[:c][mask])
        rows.append(np.stack([mean, np.sqrt(var), stderr]))
    block = np.stack(rows) if rows else np.full((1, 3) + values.shape[1:], np.nan)
    if not rows:
        counts = np.array([max(n, 1)])
    return (("trace_samples", "trace_statistic", *dims), block,
            {"long_name": "running estimates against sample count",
             "stderr_kind": "rqmc", "replicates": replicates}), counts


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
