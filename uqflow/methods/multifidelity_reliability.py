"""Multifidelity importance sampling (Peherstorfer, Cui, Marzouk & Willcox 2016, "Multifidelity
importance sampling", CMAME 300): a cheap level finds the failure region, the finest level
alone estimates P[failure], without bias.

Stage 1 runs on the coarsest level of the study's ``[levels]`` (level 0): either FORM's
improved HL-RF search (``uqflow.methods.form.Form``, composed, its rows at level 0), then
``finest_search_rounds`` rounds of the same search continued on the finest level from the
coarse design point (a second composed Form, forward differences: n + 1 finest runs a
round), whose next step centres the density (a linear finest g's design point after one
round); or the single-level cross-entropy method's rounds
(``uqflow.methods.importance_sampling.CrossEntropy``: its improved or quantile rule, a
mixture of Gaussians or, from 20 inputs on, a von Mises-Fisher-Nakagami density), each of
``coarse_samples`` coarse draws, until the rule's stop (the coarse failure region is reached)
or ``max_search_rounds``. The biasing density is

    q = (1 - w) q* + w phi,

q* the Gaussian at that centre (unit covariance) or the last cross-entropy density, phi the
standard normal density of the inputs' standard normal space and w = ``defensive_weight``:
the likelihood ratio phi / q is then at most 1 / w everywhere, so where the coarse level
misses a failure region of the finest one the estimate keeps a finite variance and stays
unbiased (it falls back to plain Monte Carlo with w N samples there).

Stage 2 runs ``samples`` draws of q on the finest level only: P[failure] is the mean of
1{g <= 0} phi / q (``uqflow.methods.importance_sampling.importance_estimate``: its standard
error, interval, coefficient of variation and effective sample size). With ``target_cov``
more batches of ``samples`` follow until the c.o.v. is reached or ``max_samples``.

With ``control_variate`` the coarsest level is also a control variate of that mean
(multifidelity Monte Carlo, Peherstorfer, Willcox & Gunzburger 2016): each batch's
M = ``coarse_draws_per_finest`` N draws of q run at level 0, the first N also at the finest,
and P = mean_N(Y_f) - alpha (mean_N(Y_c) - mean_M(Y_c)) (``control_variate_estimate``); the
coarse event g_c <= t is moved to the finest first-order index (``control_event``).

Cost: the equivalent plain Monte Carlo at the finest level for the same c.o.v. is
(1 - p) / (c.o.v.^2 p) runs of the finest level's cost c_L, against the cost of both stages,
sum_l n_l c_l (costs stated, or the median wall time of each level's runs less compile time,
as multilevel measures them). docs/rare_events_across_levels.md.

Every draw comes from the plan's SeedSequence (a child per stage and round) and from the
runs so far (the density a round samples is replayed from the earlier rounds' runs), never
from completion order: workers and resumes give the same rows.
"""

from __future__ import annotations

import hashlib
import math
import warnings as pywarnings
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
import xarray as xr
from pydantic import Field, model_validator
from scipy import stats as sps

from uqflow.errors import AccuracyWarning, StudyError
from uqflow.layout import (BIASING_COMPONENT, BIASING_MEAN, BIASING_WEIGHT, BOUND,
                           BOUND_HIGH, BOUND_LOW, COMPILE_TIME, CONFIDENCE,
                           EFFECTIVE_SAMPLE_SIZE, EQUIVALENT_FINEST_COST,
                           EQUIVALENT_FINEST_RUNS, FAILURE_COV, FAILURE_INTERVAL,
                           FAILURE_LEFT_OUT, FAILURE_PROBABILITY, FAILURE_RUNS,
                           FAILURE_STDERR, FAILURES, FIDELITY_COST, FIDELITY_RUNS,
                           FIDELITY_VALUE, FINEST_COST_RATIO, FINEST_SEARCH_INDEX,
                           FINEST_SEARCH_ROUNDS, FINEST_SEARCH_SHIFT, GUIDE_DEFENSIVE_WEIGHT,
                           CONTROL_COARSE_DRAWS, CONTROL_COEFFICIENT, CONTROL_CORRELATION,
                           CONTROL_LEFT_OUT, CONTROL_OPTIMAL_RATIO, CONTROL_PAIRS, CONTROL_THRESHOLD,
                           PLAIN_PROBABILITY, PLAIN_STDERR,
                           GUIDE_PROBABILITY, GUIDE_REACHED, GUIDE_ROUNDS, GUIDE_TOTAL_COST,
                           LEVEL, LIMIT_STATE, LOG_LIKELIHOOD_RATIO, PARAMETER,
                           RELIABILITY_INDEX, REALIZATION,
                           ROUND, SOLVER_RUNS, STATISTIC, STATISTIC_MEAN, STATISTIC_STD,
                           STATISTIC_STDERR, STATUS, STATUS_PENDING, UNITS, WALL_TIME,
                           ok_mask, output_names)
from uqflow.layout import (CE_FAMILY, CE_RULE, NAKAGAMI_M, NAKAGAMI_OMEGA, VMF_DIRECTION,
                           VMF_KAPPA)
from uqflow.methods.base import (MAX_REALIZATIONS, PropagationMethod, finish_statistics,
                                 make_design, register_method)
from uqflow.methods.fidelity_sampling import MAX_COST
from uqflow.methods.form import (STAGE, STAGE_SEARCH, STANDARD_NORMAL, STENCIL_OFFSET, Form,
                                 to_inputs)
from uqflow.methods.importance_sampling import (DEGENERATE_SHARE, FEW_EFFECTIVE,
                                                CrossEntropy, CrossEntropyRoundOptions,
                                                CrossEntropyState, GaussianMixture,
                                                defensive_mixture, effective_count,
                                                fit_gaussian_mixture, importance_estimate,
                                                log_likelihood_ratio, standard_normal,
                                                standard_normal_log_pdf,
                                                standard_normal_start)
from uqflow.methods.von_mises_fisher_nakagami import (VonMisesFisherNakagami,
                                                      fit_von_mises_fisher_nakagami)
from uqflow.probability import normal_interval, reliability_index
from uqflow.report import FigureSpec, MethodReport, new_figure, number

#: what a row is besides FORM's search rows: a cross-entropy draw at the coarse level, a
#: draw of the biasing density at the finest level, or a point (with its forward-difference
#: stencil) of the design point's refinement at the finest level (search = "form")
STAGE_CROSS_ENTROPY, STAGE_ESTIMATE = "cross-entropy", "estimate"
STAGE_FINEST_SEARCH = "finest-search"
#: control_variate = true: a draw of the biasing density run at the coarsest level (the
#: first of each batch's are the finest draws' twins: the same points)
STAGE_CONTROL = "control"
SEARCH_CROSS_ENTROPY, SEARCH_FORM = "cross-entropy", "form"
#: children of the plan's SeedSequence: (stream, round) for each round's draws
CROSS_ENTROPY_STREAM, ESTIMATE_STREAM = 1, 2
#: the level stage 1 runs at: the coarsest of [levels] (values are coarsest first)
GUIDE_LEVEL = 0
#: cross-entropy fits kept for the next replay (each round's, of a study's max_search_rounds)
MAX_KEPT_FITS = 1000


class MultifidelityImportanceOptions(CrossEntropyRoundOptions):
    # the cross-entropy search's rounds are the single-level cross-entropy method's: the same
    # rules, families and names
    limit_state: str | None = Field(None, description="the study's limit state (default: "
                                    "its only one)")
    search: Literal["cross-entropy", "form"] = Field(
        "cross-entropy", description="how stage 1 finds the failure region on the coarsest "
                                     "level: cross-entropy rounds, or FORM's design point")
    coarse_samples: int = Field(500, ge=10, le=MAX_REALIZATIONS, description="coarse-level "
                                "runs of each cross-entropy round")
    search_levels: Literal["coarsest", "all"] = Field(
        "coarsest", description="levels the cross-entropy rounds run at: the coarsest, or "
                                "every level but the finest in turn, coarsest first")
    min_spread: float = Field(1.0, gt=0, le=10, description="least standard deviation of "
                              "a fitted Gaussian in any direction, in standard normal units")
    max_search_rounds: int = Field(20, ge=1, le=1000, description="most rounds of stage 1 "
                                   "(cross-entropy rounds, or FORM iterations)")
    finest_search_rounds: int = Field(1, ge=0, le=100, description="search = form: rounds "
                                      "of the improved HL-RF search continued on the finest "
                                      "level from the coarse design point (forward "
                                      "differences, n + 1 finest runs a round); 0: the "
                                      "biasing density stays at the coarse design point")
    defensive_weight: float = Field(0.1, gt=0, lt=1, description="weight w of the standard "
                                    "normal in the biasing density (1 - w) q* + w phi")
    samples: int = Field(1000, ge=2, le=MAX_REALIZATIONS, description="finest-level runs of "
                         "the biasing density (per batch, with target_cov)")
    target_cov: float | None = Field(None, gt=0, lt=1, description="add batches of samples "
                                     "until the c.o.v. of P[failure] is at most this")
    max_samples: int = Field(10_000, ge=2, le=MAX_REALIZATIONS, description="most "
                             "finest-level runs with target_cov")
    control_variate: bool = Field(False, description="the coarsest level as a control "
                                  "variate of the estimate (multifidelity Monte Carlo): each "
                                  "batch's draws also run at level 0, with "
                                  "coarse_draws_per_finest times as many coarse draws")
    control_event: Literal["matched", "coarse"] = Field(
        "matched", description="control_variate: the coarse event of the control, "
                               "g_c <= t: matched, t moves the coarse event to the finest "
                               "level's first-order reliability index (search = form with its "
                               "refinement; t = 0 otherwise); coarse, t = 0")
    coarse_draws_per_finest: int = Field(10, ge=1, le=1000, description="control_variate: "
                                         "coarse draws M of a batch per finest draw N (M / N; "
                                         "the first N are the finest draws' points)")
    confidence: float = Field(0.95, gt=0, lt=1, description="level of the interval")
    costs: Literal["measured"] | list[float] = Field(
        "measured", description="cost of one run per level, coarsest first: 'measured' "
                                "(median wall time less compile time) or numbers")

    @model_validator(mode="after")
    def _applies(self):
        self.only_where("coarse_samples", self.search == SEARCH_CROSS_ENTROPY,
                        'search = "cross-entropy"')
        for key in ("rule", "smoothing_cov", "rho", "family", "components", "covariance",
                    "min_spread", "search_levels"):
            self.only_where(key, self.search == SEARCH_CROSS_ENTROPY,
                            'search = "cross-entropy"')
        self.only_where("rho", self.rule == "quantile", 'rule = "quantile" (the improved '
                        'rule sets its targets by smoothing_cov)')
        self.only_where("smoothing_cov", self.rule == "improved", 'rule = "improved"')
        for key in ("components", "covariance", "min_spread"):
            self.only_where(key, self.family != "vmfn", "the gaussian family (family = "
                            '"vmfn" fits a direction and a radius)')
        self.only_where("finest_search_rounds", self.search == SEARCH_FORM, 'search = "form"')
        self.only_where("max_samples", self.target_cov is not None, "target_cov")
        for key in ("coarse_draws_per_finest", "control_event"):
            self.only_where(key, self.control_variate, "control_variate = true")
        if isinstance(self.costs, list) and not all(0 < c <= MAX_COST for c in self.costs):
            raise ValueError(f"every cost must be > 0 and <= {MAX_COST:.2g} (costs are "
                             f"relative, any unit; the study's total must stay a finite "
                             f"number), got {self.costs}")
        return self


@dataclass
class Guide:
    """Stage 1 replayed from the coarse runs: the biasing density once it is built."""

    rounds: int                          # stage-1 rounds run so far
    done: bool                           # whether stage 1 has ended
    density: GaussianMixture | None      # (1 - w) q* + w phi, once done
    reached: bool = False                # the coarse failure region was found
    coarse_probability: float = math.nan  # stage 1's own P[failure] at the coarse level
    note: str = ""                       # why stage 1 did not reach it, in words
    next_density: GaussianMixture | None = None  # what the next cross-entropy round draws
    next_level: int = 0                  # and at which level
    # search = "form"'s refinement at the finest level: the point of its next round (None:
    # none to run), its rounds so far, the first-order beta where it ended, and how far it
    # moved the centre from the coarse design point
    finest_next: np.ndarray | None = None
    finest_rounds: int = 0
    finest_beta: float = math.nan
    finest_shift: float = math.nan
    finest_note: str = ""                # why the refinement fell back, in words
    # the cross-entropy search: the family its last fit is of, and that fit's effective
    # count of draws (Kish)
    family: str = ""
    fit_effective: float = math.nan
    # control_event = "matched": the coarse level's first-order reliability index and the
    # length of its g's gradient at the coarse design point (NaN: none)
    coarse_beta: float = math.nan
    coarse_slope: float = math.nan

    def control_threshold(self, event: str) -> float:
        """t of the control's coarse event g_c <= t: with "matched", the coarse g's
        linearization shifted to the finest's first-order index, t = (beta_c - beta_f)
        |grad g_c| (0 without both indices)."""
        shift = (self.coarse_beta - self.finest_beta) * self.coarse_slope
        return float(shift) if event == "matched" and np.isfinite(shift) else 0.0


@register_method("multifidelity-importance-sampling")
class MultifidelityImportanceSampling(PropagationMethod):
    """P[failure] at the finest level from a biasing density found on the coarsest."""

    Options: ClassVar = MultifidelityImportanceOptions
    uses_levels: ClassVar[bool] = True
    extends: ClassVar[bool] = True
    uses_limit_states: ClassVar[bool] = True

    # ------------------------------------------------------------------ load-time checks
    def check_limit_states(self, limit_states) -> None:
        form = Form(limit_state=self.options.limit_state,
                    max_iterations=self.options.max_search_rounds)
        form.name = self.name
        try:
            form.check_limit_states(limit_states)
        except StudyError as exc:
            # FORM refuses systems; the cross-entropy search takes them (a system's margin
            # is min or max of its members', and its sign is the event)
            if not (self.options.search == SEARCH_CROSS_ENTROPY and "system" in exc.reason
                    and limit_states is not None):
                raise
            form.limit_states, form.limit_state = limit_states, self.options.limit_state
        self.limit_states, self.limit_state = limit_states, form.limit_state
        self._form = form
        # the refinement at the finest level: FORM's search from the coarse design point,
        # forward differences (n + 1 finest runs a round, where central ones cost 2n + 1),
        # as many rounds as asked, no design-point check (the coarse level's search had
        # the chance to see the failure region's shape)
        rounds = getattr(self.options, "finest_search_rounds", 0)
        self._finest_form = None
        if self.options.search == SEARCH_FORM and rounds > 0:
            finest = Form(limit_state=form.limit_state, gradient="forward",
                          max_iterations=rounds, design_point_check=False)
            finest.name = self.name
            finest.limit_states, finest.limit_state = limit_states, form.limit_state
            self._finest_form = finest

    def check_levels(self, levels) -> None:
        self.n_levels = len(levels)
        self.level_values = [float(v) for v in levels.values]
        if isinstance(self.options.costs, list) and len(self.options.costs) != self.n_levels:
            raise StudyError(f"costs has {len(self.options.costs)} values for "
                             f"{self.n_levels} levels", key="method.costs")

    def margins(self, runs: xr.Dataset) -> np.ndarray:
        """g of every realization (NaN where a run did not finish ok)."""
        return self._form.margins(runs)

    # ------------------------------------------------------------------ designs
    def plan(self, space, fields, seed):
        self.check(space, fields)
        if getattr(self, "_form", None) is None:
            raise StudyError(f"method '{self.name}' needs a limit state: add a "
                             f"[[limit_states]] table", key="limit_states")
        if not hasattr(self, "n_levels"):
            raise StudyError(f"method '{self.name}' needs the study's [levels]", key="levels")
        if self.options.search == SEARCH_CROSS_ENTROPY and self.options.family == "vmfn" \
                and len(space) < 2:
            raise StudyError(f'family = "vmfn" needs at least 2 inputs (a direction on a '
                             f'sphere), the study has {len(space)}', key="method.family")
        self._space, self._seed = space, seed
        if getattr(self, "_finest_form", None) is not None:
            self._finest_form._space = space
        if self.options.search == SEARCH_FORM:
            return self.at_level(self._form.plan(space, fields, seed), GUIDE_LEVEL)
        return self.draw_rows(standard_normal(len(space)), CROSS_ENTROPY_STREAM, 0,
                              self.options.coarse_samples, GUIDE_LEVEL, STAGE_CROSS_ENTROPY)

    def rng(self, stream: int, round_: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence(
            self._seed.entropy, spawn_key=(*self._seed.spawn_key, stream, round_)))

    def draw_rows(self, density, stream, round_, n, level, stage) -> xr.Dataset:
        u = np.asarray(density.sample(self.rng(stream, round_), n), dtype=float)
        u = u.reshape(n, len(self._space))
        return self.rows_at(density, u, round_, np.full(n, level), np.full(n, stage))

    def control_rows(self, density, batch: int, n: int, round_: int) -> xr.Dataset:
        """control_variate = true: one batch's M = ``n`` coarse_draws_per_finest draws of q
        (one stream, as a batch without the control), the first ``n`` at the finest level,
        then all M at the coarsest (the first n of them the finest draws' twins)."""
        m = n * self.options.coarse_draws_per_finest
        u = np.asarray(density.sample(self.rng(ESTIMATE_STREAM, batch), m), dtype=float)
        u = u.reshape(m, len(self._space))
        level = np.concatenate([np.full(n, self.n_levels - 1), np.full(m, GUIDE_LEVEL)])
        stage = np.array([STAGE_ESTIMATE] * n + [STAGE_CONTROL] * m, dtype=object)
        return self.rows_at(density, np.vstack([u[:n], u]), round_, level, stage)

    def rows_at(self, density, u, round_, level, stage) -> xr.Dataset:
        """The design of the points ``u`` (standard normal) drawn from ``density``, each
        row at its ``level`` and ``stage``."""
        n = u.shape[0]
        design = make_design(self._space, to_inputs(self._space, u),
                             **{ROUND: (REALIZATION, np.full(n, round_, dtype=np.int64))})
        design = design.assign_coords({
            STANDARD_NORMAL: ((REALIZATION, PARAMETER), u,
                              {"long_name": "point in standard normal space"}),
            STENCIL_OFFSET: ((REALIZATION, PARAMETER), np.zeros_like(u)),
            STAGE: (REALIZATION, np.asarray(stage, dtype=object))})
        if self.options.search == SEARCH_CROSS_ENTROPY:
            # the cross-entropy rounds replay their fits from these (as the single-level
            # method does); every row of the search carries one, so the rounds concatenate
            design = design.assign_coords({LOG_LIKELIHOOD_RATIO: (REALIZATION, np.asarray(
                log_likelihood_ratio(density, u), dtype=float), {
                    "long_name": "log phi(u) - log q(u) of the density the row was drawn "
                                 "from"})})
        design[LEVEL] = (REALIZATION, np.asarray(level, dtype=np.int64))
        return design

    @staticmethod
    def at_level(design: xr.Dataset, level: int) -> xr.Dataset:
        design[LEVEL] = (REALIZATION, np.full(design.sizes[REALIZATION], level,
                                              dtype=np.int64))
        return design

    def extend(self, design, runs):
        guide = self.guide(runs)
        stage = runs[STAGE].values
        last_round = int(runs[ROUND].values.max())
        if not guide.done:
            if guide.finest_next is not None:
                rows = self._finest_form.search_rows(guide.finest_next, last_round + 1)
                rows = rows.assign_coords({STAGE: (REALIZATION, np.full(
                    rows.sizes[REALIZATION], STAGE_FINEST_SEARCH, dtype=object))})
                return self.at_level(rows, self.n_levels - 1)
            if self.options.search == SEARCH_FORM:
                search = self.stage_rows(runs, stage == STAGE_SEARCH)
                return self.at_level(self._form.extend(search, search), GUIDE_LEVEL)
            return self.draw_rows(guide.next_density, CROSS_ENTROPY_STREAM, guide.rounds,
                                  self.options.coarse_samples, guide.next_level,
                                  STAGE_CROSS_ENTROPY)
        estimate = stage == STAGE_ESTIMATE
        batches = np.unique(runs[ROUND].values[estimate]).size
        drawn = int(estimate.sum())
        if batches:
            opts = self.options
            if opts.target_cov is None or drawn >= opts.max_samples:
                return None
            found = self.estimate(runs, guide)
            if found is not None and found.cov <= opts.target_cov:
                return None
        n = self.options.samples
        if self.options.target_cov is not None:
            n = min(n, self.options.max_samples - drawn)
        if self.options.control_variate:
            return self.control_rows(guide.density, batches, n, last_round + 1)
        rows = self.draw_rows(guide.density, ESTIMATE_STREAM, batches, n, self.n_levels - 1,
                              STAGE_ESTIMATE)
        rows[ROUND].values[:] = last_round + 1
        return rows

    @staticmethod
    def stage_rows(runs: xr.Dataset, mask: np.ndarray) -> xr.Dataset:
        return runs.isel({REALIZATION: np.flatnonzero(mask)})

    # ------------------------------------------------------------------ stage 1, replayed
    def guide(self, runs: xr.Dataset) -> Guide:
        """Stage 1 after the runs so far, from the runs alone."""
        if self.options.search == SEARCH_FORM:
            return self.form_guide(runs)
        return self.cross_entropy_guide(runs)

    def biasing(self, centre_density):
        """(1 - w) q* + w phi."""
        if isinstance(centre_density, GaussianMixture):
            return with_defensive(centre_density, self.options.defensive_weight)
        return DefensiveMixture(centre_density, self.options.defensive_weight)

    def cross_entropy(self) -> "GuideCrossEntropy":
        """The single-level cross-entropy method with this method's options, whose rounds
        replay one level's rows."""
        opts = self.options
        given = {key: getattr(opts, key) for key in (
            "rule", "family", "smoothing_cov", "rho", "components", "covariance")
            if key in opts.model_fields_set}
        method = GuideCrossEntropy(samples=opts.coarse_samples, **given)
        method.floor = opts.min_spread**2
        if getattr(self, "_fits", None) is None:
            self._fits = {}
        method.fits = self._fits
        return method

    def form_guide(self, runs: xr.Dataset) -> Guide:
        search_rows = self.stage_rows(runs, runs[STAGE].values == STAGE_SEARCH)
        n = search_rows.sizes[PARAMETER]
        if not search_rows.sizes[REALIZATION]:
            return Guide(0, False, None)
        search = self._form.replay(search_rows)
        rounds = len(search.iterations)
        if search.next_point() is not None:
            return Guide(rounds, False, None)
        centre = search.point.u if search.point is not None else np.zeros(n)
        beta = math.nan
        if search.point is not None:
            gradient = search.point.gradient
            beta = float(-gradient @ search.point.u / np.linalg.norm(gradient))
        note = "" if search.converged else \
            f"FORM on the coarse level did not converge ({search.stopped})"
        guide = Guide(rounds, True, None, reached=bool(search.converged),
                      coarse_probability=float(sps.norm.sf(beta)), note=note)
        if search.point is not None:
            slope = float(np.linalg.norm(search.point.gradient))
            if slope > 0:
                guide.coarse_slope = slope
                guide.coarse_beta = float((search.point.g - search.point.gradient
                                           @ search.point.u) / slope)
        if getattr(self, "_finest_form", None) is not None:
            centre = self.refine_at_finest(runs, centre, guide)
            if guide.finest_next is not None:
                guide.done = False
                return guide
        guide.density = defensive_mixture(centre,
                                          defensive_weight=self.options.defensive_weight)
        return guide

    def refine_at_finest(self, runs: xr.Dataset, coarse: np.ndarray, guide: Guide):
        """The centre of the biasing density after the finest level's rounds so far, from
        their runs alone: FORM's improved HL-RF search continued at the finest level from
        the coarse design point. Its last accepted point u with g and grad g there proposes
        u + lambda d (d the HL-RF step, lambda the line search's current step, 1 after an
        accepted trial): for a linear finest g that is its design point exactly, whatever
        the coarse point's error. Sets ``guide.finest_next`` while rounds remain; falls back
        to the coarse design point, with a note, where g or its gradient is unusable."""
        mask = runs[STAGE].values == STAGE_FINEST_SEARCH
        if not mask.any():
            guide.finest_next = coarse
            return coarse
        rows = self.stage_rows(runs, mask)
        # the finest rows replay as FORM's own search rows
        rows = rows.assign_coords({STAGE: (REALIZATION, np.full(rows.sizes[REALIZATION],
                                                                STAGE_SEARCH, dtype=object))})
        search = self._finest_form.replay(rows)
        guide.finest_rounds = len(search.iterations)
        following = search.next_point()
        if following is not None:
            guide.finest_next = following
            return coarse
        point = search.point
        if point is None:
            guide.finest_note = (
                "the finest level's g or its gradient at the coarse design point is not "
                "usable (a run of its stencil failed, or the gradient is zero): the biasing "
                "density stays at the coarse design point")
            guide.finest_shift = 0.0
            return coarse
        centre = point.u + search.step * search.direction
        norm = float(np.linalg.norm(point.gradient))
        guide.finest_beta = float((point.g - point.gradient @ point.u) / norm)
        guide.finest_shift = float(np.linalg.norm(centre - coarse))
        return centre

    def cross_entropy_guide(self, runs: xr.Dataset) -> Guide:
        """The single-level cross-entropy method's rounds (its rule and family), replayed
        level by level from the rows' margins and stored log likelihood ratios: a level's
        rounds start from the density the level below ended with."""
        stage = runs[STAGE].values
        rounds_of = runs[ROUND].values
        level_of = runs[LEVEL].values
        mask = stage == STAGE_CROSS_ENTROPY
        g_all = self.margins(runs)
        u_all = np.asarray(runs[STANDARD_NORMAL].values, dtype=float)
        ratio_all = np.asarray(runs[LOG_LIKELIHOOD_RATIO].values, dtype=float) \
            if LOG_LIKELIHOOD_RATIO in runs.coords else np.full(runs.sizes[REALIZATION],
                                                                 np.nan)
        # the same rows replay to the same guide: computed once (extend, analyze and the
        # output moments each ask), keyed on everything the replay reads
        rows = np.flatnonzero(mask)
        key = hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in (
            rows, g_all[rows], rounds_of[rows], level_of[rows], u_all[rows],
            ratio_all[rows]))).hexdigest()
        cached = getattr(self, "_cross_entropy_guide", None)
        if cached is not None and cached[0] == key:
            return cached[1]
        guide = self.replay_cross_entropy(mask, g_all, rounds_of, level_of, stage, u_all,
                                          ratio_all)
        self._cross_entropy_guide = (key, guide)
        return guide

    def replay_cross_entropy(self, mask, g_all, rounds_of, level_of, stage, u_all,
                             ratio_all) -> Guide:
        """``cross_entropy_guide``'s rounds, level by level."""
        opts = self.options
        n = u_all.shape[1]
        axes = np.arange(n)
        done = int(np.unique(rounds_of[mask]).size)
        method = self.cross_entropy()
        family = method.options.family_for(n)
        density = standard_normal_start(n)
        # the level the rounds run at: the next one up each time a level's failure region
        # is reached, until the last level before the finest (search_levels = "all")
        last = self.n_levels - 2 if opts.search_levels == "all" else GUIDE_LEVEL
        for level in range(last + 1):
            rows = np.flatnonzero(mask & (level_of == level))
            state = CrossEntropyState(density)
            if rows.size:
                state = method.replay_rounds(state, g_all[rows], rounds_of[rows], stage[rows],
                                             ratio_all[rows], u_all[rows], axes)
            effective = state.effective[-1] if state.effective else math.nan
            if state.stopped:
                note = f"cross-entropy at level {level} stopped: {state.stopped}"
                return Guide(done, True, self.biasing(state.density), note=note,
                             family=family, fit_effective=effective)
            if state.reached and level < last:
                density = state.density
                continue
            if state.reached:
                # the round that reached the failure region: its own weighted estimate of
                # this level's P[failure]
                final = rows[rounds_of[rows] == rounds_of[rows].max()]
                judged = final[np.isfinite(g_all[final])]
                probability = importance_estimate(g_all[judged] <= 0, ratio_all[judged],
                                                  opts.confidence).probability
                return Guide(done, True, self.biasing(state.density), reached=True,
                             coarse_probability=float(probability), family=family,
                             fit_effective=effective)
            if done >= opts.max_search_rounds:
                note = (f"the cross-entropy rounds did not reach the failure region of level "
                        f"{last} in max_search_rounds = {opts.max_search_rounds}")
                return Guide(done, True, self.biasing(state.density), note=note,
                             family=family, fit_effective=effective)
            return Guide(done, False, None, next_density=state.density, next_level=level,
                         family=family, fit_effective=effective)
        raise AssertionError("unreachable: the last level returns")

    # ------------------------------------------------------------------ stage 2
    def estimate(self, runs: xr.Dataset, guide: Guide):
        """The importance-sampling estimate from the finest-level rows (None without any);
        with control_variate, the control-variate estimate (``control_estimate``)."""
        plain = self.plain_estimate(runs, guide)
        if plain is None or not self.options.control_variate:
            return plain
        return self.control_estimate(runs, guide, plain)

    def plain_estimate(self, runs: xr.Dataset, guide: Guide):
        """The mean of 1{g <= 0} phi / q over the finest-level rows that ran ok."""
        rows = np.flatnonzero(runs[STAGE].values == STAGE_ESTIMATE)
        if not rows.size or guide.density is None:
            return None
        g = self.margins(runs)[rows]
        judged = np.isfinite(g)
        if not judged.any():
            return None
        u = np.asarray(runs[STANDARD_NORMAL].values, dtype=float)[rows][judged]
        log_ratio = standard_normal_log_pdf(u) - guide.density.log_pdf(u)
        return importance_estimate(np.asarray(g[judged] <= 0), log_ratio,
                                   self.options.confidence)

    def control_estimate(self, runs: xr.Dataset, guide: Guide, plain) -> "ControlEstimate":
        """The control-variate estimate from each batch's pairs (its i-th finest row and
        its i-th coarse row, drawn at the same point) and all its coarse rows: a pair whose
        either run failed is left out of the pairs (its finest run, if ok, counted in
        ``left_out``), a coarse row that failed out of the M."""
        stage, rounds = runs[STAGE].values, runs[ROUND].values
        g = self.margins(runs)
        u = np.asarray(runs[STANDARD_NORMAL].values, dtype=float)
        first, rest = [], []
        left_out = 0
        for batch in np.unique(rounds[stage == STAGE_ESTIMATE]):
            fine = np.flatnonzero((stage == STAGE_ESTIMATE) & (rounds == batch))
            coarse = np.flatnonzero((stage == STAGE_CONTROL) & (rounds == batch))
            twins = coarse[:fine.size]
            if twins.size != fine.size or not np.array_equal(u[fine], u[twins]):
                raise AssertionError("a batch's coarse rows do not start with its finest "
                                     "rows' points")
            both = np.isfinite(g[fine]) & np.isfinite(g[twins])
            left_out += int((np.isfinite(g[fine]) & ~both).sum())
            first += [np.column_stack([fine[both], twins[both]])]
            rest += [coarse[fine.size:][np.isfinite(g[coarse[fine.size:]])]]
        pairs = np.vstack(first) if first else np.zeros((0, 2), dtype=int)
        if pairs.shape[0] < 2:
            return plain        # analyze says the control was not used
        coarse_rows = np.concatenate([pairs[:, 1], *rest]).astype(int)
        log_ratio = standard_normal_log_pdf(u[coarse_rows]) - \
            guide.density.log_pdf(u[coarse_rows])
        threshold = guide.control_threshold(self.options.control_event)
        found = control_variate_estimate(g[pairs[:, 0]] <= 0, g[coarse_rows] <= threshold,
                                         log_ratio, self.options.confidence)
        found.threshold = threshold
        found.plain, found.left_out = plain, left_out
        found.effective_sample_size = plain.effective_sample_size
        return found

    def run_costs(self, runs: xr.Dataset) -> np.ndarray:
        """Cost of one run per level: stated, or the median wall time of the level's runs
        that ran ok, less numba's compile time (paid once per process); NaN for a level
        without such runs."""
        if isinstance(self.options.costs, list):
            return np.asarray(self.options.costs, dtype=float)
        level = runs[LEVEL].values
        ok = ok_mask(runs)
        seconds = np.asarray(runs[WALL_TIME].values, dtype=float)
        if COMPILE_TIME in runs:
            seconds = seconds - np.nan_to_num(np.asarray(runs[COMPILE_TIME].values,
                                                         dtype=float), nan=0.0)
        return np.array([float(np.median(seconds[ok & (level == lv)]))
                         if np.any(ok & (level == lv)) else math.nan
                         for lv in range(self.n_levels)])

    # ------------------------------------------------------------------ statistics
    def analyze(self, design, runs):
        opts = self.options
        guide = self.guide(runs)
        found = self.estimate(runs, guide)
        warnings = []
        stage = runs[STAGE].values
        estimate_rows = stage == STAGE_ESTIMATE
        ok = ok_mask(runs)
        left_out = int((estimate_rows & ~ok & (runs[STATUS].values != STATUS_PENDING)).sum())
        if guide.note:
            warnings.append(f"{guide.note}: the biasing density is built on what it found; "
                            f"the estimate stays unbiased through the defensive component "
                            f"but may need many more samples")
        if found is None:
            warnings.append("no finest-level run of the biasing density finished ok: "
                            "P[failure] is not estimated")
        if left_out:
            warnings.append(f"{left_out} finest-level runs did not run ok and are left out "
                            f"(neither failure nor safe): P[failure] is biased if solver "
                            f"errors depend on the inputs")
        if guide.finest_note:
            warnings.append(guide.finest_note)
        finest_search = stage == STAGE_FINEST_SEARCH
        finest_search_failed = int((finest_search & ~ok).sum())
        if finest_search_failed:
            warnings.append(f"{finest_search_failed} finest-level runs of the design point's "
                            f"refinement did not run ok")
        control_rows = stage == STAGE_CONTROL
        coarse_failed = int(((~estimate_rows) & ~finest_search & ~control_rows & ~ok).sum())
        control_failed = int((control_rows & ~ok & (runs[STATUS].values != STATUS_PENDING))
                             .sum())
        controlled = isinstance(found, ControlEstimate)
        if opts.control_variate and found is not None and not controlled:
            warnings.append("the coarse control variate is not used: fewer than 2 pairs of "
                            "finest and coarse runs ran ok; P[failure] is the plain estimate")
        if control_failed:
            left = found.left_out if controlled else 0
            warnings.append(f"{control_failed} coarse-level runs of the control variate did "
                            f"not run ok and are left out of it ({left} finest runs ok whose "
                            f"coarse twin failed are left out of the pairs, kept in the plain "
                            f"estimate): the control stays unbiased if coarse solver errors "
                            f"do not depend on the inputs")
        if coarse_failed:
            warnings.append(f"{coarse_failed} coarse-level runs of stage 1 did not run ok; "
                            f"stage 1 used the others")
        p, stderr, low, high, cov, ess, n, failures = (math.nan,) * 6 + (0, 0)
        if found is not None:
            p, stderr, low, high = found.probability, found.stderr, found.low, found.high
            cov, ess = found.cov, found.effective_sample_size
            n = int(found.plain.n if controlled else found.n)
            judged = np.isfinite(self.margins(runs)[estimate_rows])
            failures = int((self.margins(runs)[estimate_rows][judged] <= 0).sum())
            if failures == 0:
                warnings.append("no finest-level run of the biasing density failed: "
                                "P[failure] is 0 with an undefined c.o.v.; the biasing "
                                "density may miss the failure region")
            elif ess < FEW_EFFECTIVE and ess < DEGENERATE_SHARE * failures:
                # both: a share of the failing draws alone (importance-sampling's rule) would
                # call a density at the coarse design point in many inputs degenerate where
                # its reported c.o.v. holds (benchmarks/reliability_levels.py, linear-100d:
                # ESS near a tenth of the failures, some 30 draws)
                warnings.append(
                    f"the importance weights have degenerated: effective sample size "
                    f"{ess:.3g} of {failures} failing finest-level draws; a few draws carry "
                    f"the estimate (the biasing density misses part of the finest failure "
                    f"region, or is too narrow): it stays unbiased, but its standard error "
                    f"and interval cannot be trusted")
            elif ess < FEW_EFFECTIVE:
                warnings.append(f"effective sample size {ess:.3g} < {FEW_EFFECTIVE:g}: the "
                                f"normal interval rests on too few effective draws")
        n_inputs = runs.sizes[PARAMETER]
        if guide.fit_effective < n_inputs:
            warnings.append(
                f"the last cross-entropy fit rests on {guide.fit_effective:.3g} effective "
                f"draws for {n_inputs} inputs: its centre is off by about sqrt(d / n) = "
                f"{math.sqrt(n_inputs / guide.fit_effective):.2g} (standard normal units, or "
                f"radians), which can inflate the weights' second moment by about "
                f"e^(d / n); raise coarse_samples or use search = \"form\"")
        costs = self.run_costs(runs)
        level = runs[LEVEL].values
        done = runs[STATUS].values != STATUS_PENDING
        level_runs = np.array([int((done & (level == lv)).sum())
                               for lv in range(self.n_levels)])
        spent = float(np.nansum(level_runs * costs))
        with np.errstate(divide="ignore", invalid="ignore"):
            equivalent = (1.0 - p) / (cov**2 * p) if p > 0 and cov > 0 else math.nan
        equivalent_cost = equivalent * costs[-1]
        ratio = equivalent_cost / spent if spent > 0 else math.nan
        one = (LIMIT_STATE,)
        data = {
            FAILURE_PROBABILITY: (one, [p], {"long_name": "failure probability at the "
                                                          "finest level", UNITS: "1"}),
            FAILURE_STDERR: (one, [stderr], {"long_name": "standard error of P[failure]",
                                             UNITS: "1"}),
            FAILURE_INTERVAL: ((LIMIT_STATE, BOUND), [[low, high]], {UNITS: "1"}),
            FAILURE_COV: (one, [cov], {UNITS: "1"}),
            RELIABILITY_INDEX: (one, [float(reliability_index(p))], {UNITS: "1"}),
            FAILURES: (one, [failures]),
            FAILURE_RUNS: (one, [n]),
            FAILURE_LEFT_OUT: (one, [left_out]),
            EFFECTIVE_SAMPLE_SIZE: (one, [ess], {"long_name": "effective sample size of "
                                                              "the importance weights"}),
            EQUIVALENT_FINEST_RUNS: (one, [equivalent], {
                "long_name": "finest-level runs plain Monte Carlo needs for the same c.o.v., "
                             "(1 - p) / (cov^2 p)"}),
            EQUIVALENT_FINEST_COST: (one, [equivalent_cost], {
                "long_name": "their cost at the finest level's cost per run"}),
            FINEST_COST_RATIO: (one, [ratio], {
                "long_name": "equivalent finest-level Monte Carlo cost over this study's"}),
            GUIDE_PROBABILITY: (one, [guide.coarse_probability], {
                "long_name": "stage 1's P[failure] at the coarsest level (a guide: biased)",
                UNITS: "1"}),
            FINEST_SEARCH_INDEX: (one, [guide.finest_beta], {
                "long_name": "first-order reliability index of the finest level's "
                             "linearization where the design point's refinement ended",
                UNITS: "1"}),
            FIDELITY_RUNS: ((LEVEL,), level_runs),
            FIDELITY_COST: ((LEVEL,), costs, {UNITS: "s" if opts.costs == "measured"
                                           else "stated"}),
        }
        if opts.control_variate:
            data.update(self.control_statistics(found, costs))
        if isinstance(guide.density, GaussianMixture):
            data[BIASING_WEIGHT] = ((BIASING_COMPONENT,), np.asarray(guide.density.weights, float))
            data[BIASING_MEAN] = ((BIASING_COMPONENT, PARAMETER),
                                  np.asarray(guide.density.means, float),
                                  {"long_name": "component means in standard normal space",
                                   UNITS: "1"})
        stats = xr.Dataset(data, coords={LIMIT_STATE: [self.limit_state],
                                         BOUND: [BOUND_LOW, BOUND_HIGH],
                                         LEVEL: np.arange(self.n_levels),
                                         PARAMETER: runs[PARAMETER].values})
        stats = stats.assign_coords({FIDELITY_VALUE: (LEVEL, np.asarray(self.level_values,
                                                                    dtype=float))})
        if isinstance(guide.density, DefensiveMixture):
            vmfn = guide.density.density
            stats[VMF_DIRECTION] = ((PARAMETER,), vmfn.mean_direction, {
                "long_name": "mean direction of the von Mises-Fisher part of the biasing "
                             "density in standard normal space", UNITS: "1"})
            stats.attrs.update({VMF_KAPPA: float(vmfn.kappa), NAKAGAMI_M: float(vmfn.m),
                                NAKAGAMI_OMEGA: float(vmfn.omega)})
        if opts.search == SEARCH_CROSS_ENTROPY:
            stats.attrs.update({CE_RULE: opts.rule, CE_FAMILY: guide.family})
        self.output_moments(stats, runs, guide, estimate_rows)
        for message in warnings:
            pywarnings.warn(message, AccuracyWarning, stacklevel=2)
        stats = finish_statistics(stats, design, runs, self.name, warnings)
        state = self.limit_states[self.limit_state]
        stats.attrs[LIMIT_STATE] = self.limit_state
        stats.attrs.update({CONFIDENCE: opts.confidence, "search": opts.search,
                            GUIDE_ROUNDS: guide.rounds, GUIDE_REACHED: int(guide.reached),
                            FINEST_SEARCH_ROUNDS: guide.finest_rounds,
                            FINEST_SEARCH_SHIFT: guide.finest_shift,
                            GUIDE_DEFENSIVE_WEIGHT: opts.defensive_weight,
                            "limit_state_event": getattr(state, "describe", lambda: "")(),
                            GUIDE_TOTAL_COST: spent})
        return stats

    def control_statistics(self, found, costs) -> dict:
        """control_variate = true: what the estimate rests on, and the plain estimate
        beside it (NaN where the control was not used)."""
        one = (LIMIT_STATE,)
        controlled = isinstance(found, ControlEstimate)
        plain = found.plain if controlled else found
        rho = found.correlation if controlled else math.nan
        with np.errstate(divide="ignore", invalid="ignore"):
            # MFMC's optimal M / N for two models: sqrt(c_f rho^2 / (c_c (1 - rho^2))),
            # unbounded at |rho| = 1 (to rounding: the coarse terms are the finest's)
            optimal = math.nan
            if np.isfinite(rho) and np.all(np.isfinite(costs)):
                optimal = math.sqrt(costs[-1] * rho**2 / (costs[GUIDE_LEVEL]
                                                          * (1.0 - rho**2))) \
                    if rho**2 < 1 else math.inf
        return {
            PLAIN_PROBABILITY: (one, [plain.probability if plain is not None else math.nan], {
                "long_name": "importance-sampling estimate without the coarse control",
                UNITS: "1"}),
            PLAIN_STDERR: (one, [plain.stderr if plain is not None else math.nan], {
                "long_name": "its standard error", UNITS: "1"}),
            CONTROL_CORRELATION: (one, [rho], {
                "long_name": "correlation of the finest and coarse weighted indicators over "
                             "the pairs", UNITS: "1"}),
            CONTROL_COEFFICIENT: (one, [found.coefficient if controlled else math.nan], {
                "long_name": "control coefficient alpha = cov(Y_f, Y_c) / var(Y_c)",
                UNITS: "1"}),
            CONTROL_PAIRS: (one, [found.n if controlled else 0]),
            CONTROL_COARSE_DRAWS: (one, [found.coarse_draws if controlled else 0]),
            CONTROL_LEFT_OUT: (one, [found.left_out if controlled else 0]),
            CONTROL_THRESHOLD: (one, [found.threshold if controlled else math.nan], {
                "long_name": "t of the control's coarse event g <= t, in g's unit"}),
            CONTROL_OPTIMAL_RATIO: (one, [optimal], {
                "long_name": "MFMC's optimal coarse draws per finest draw at the levels' "
                             "costs and this correlation", UNITS: "1"}),
        }

    def output_moments(self, stats, runs, guide, estimate_rows) -> None:
        """Each output's mean, std and the mean's standard error over the inputs'
        distribution from the finest-level runs, self-normalized by their importance weights
        (bounded by 1 / w, so never worse than plain Monte Carlo with w N runs; the standard
        error is the delta method's, sqrt(sum w_i^2 (y_i - mean)^2) / sum w_i)."""
        ok = ok_mask(runs) & estimate_rows
        u = np.asarray(runs[STANDARD_NORMAL].values, dtype=float)[ok]
        weights = np.zeros(0)
        if u.size and guide.density is not None:
            weights = np.exp(standard_normal_log_pdf(u) - guide.density.log_pdf(u))
        for out in output_names(runs):
            values = np.asarray(runs[out].values, dtype=float)[ok]
            shape = runs[out].shape[1:]
            mean = std = stderr = np.full(shape, np.nan)
            if weights.size and np.sum(weights) > 0:
                w = (weights / np.sum(weights)).reshape(-1, *([1] * len(shape)))
                mean = np.sum(w * values, axis=0)
                std = np.sqrt(np.sum(w * (values - mean) ** 2, axis=0))
                stderr = np.sqrt(np.sum(w**2 * (values - mean) ** 2, axis=0))
            stats[out] = xr.DataArray(np.stack([mean, std, stderr]),
                                      dims=(STATISTIC, *runs[out].dims[1:]))
        stats.coords[STATISTIC] = [STATISTIC_MEAN, STATISTIC_STD, STATISTIC_STDERR]
        for dim in {d for out in output_names(runs) for d in runs[out].dims[1:]}:
            if dim in runs.coords:
                stats.coords[dim] = runs[dim]

    # ------------------------------------------------------------------ report
    @classmethod
    def report(cls, view):
        """P[failure] with its interval and c.o.v., the two stages' runs and what plain Monte
        Carlo at the finest level would have cost."""
        stats = view.stats
        attrs = stats.attrs
        name = str(attrs.get(LIMIT_STATE, "?"))

        def value(key, *, bound=None):
            if key not in stats:
                return math.nan
            at = stats[key].isel({LIMIT_STATE: 0})
            return float(at.sel({BOUND: bound}) if bound else at)

        level = f"{100 * float(attrs.get(CONFIDENCE, 0.95)):g} %"
        event = f" ({attrs['limit_state_event']})" if attrs.get("limit_state_event") else ""
        runs = [int(r) for r in stats[FIDELITY_RUNS].values] if FIDELITY_RUNS in stats else []
        values = [number(v) for v in stats[FIDELITY_VALUE].values] if FIDELITY_VALUE in stats.coords \
            else []
        notes = [
            f"P[failure of {name}]{event} at the finest level = "
            f"{number(value(FAILURE_PROBABILITY))} ({level} interval "
            f"{number(value(FAILURE_INTERVAL, bound=BOUND_LOW))} .. "
            f"{number(value(FAILURE_INTERVAL, bound=BOUND_HIGH))}), stderr "
            f"{number(value(FAILURE_STDERR))}, c.o.v. {number(value(FAILURE_COV))}, beta = "
            f"{number(value(RELIABILITY_INDEX))}; {int(value(FAILURES))} failures in "
            f"{int(value(FAILURE_RUNS))} finest-level runs, effective sample size "
            f"{number(value(EFFECTIVE_SAMPLE_SIZE))}",
            f"stage 1 ({attrs.get('search', '?')}"
            + (f", {attrs[CE_RULE]} rule, {attrs.get(CE_FAMILY, '?')} family"
               if CE_RULE in attrs else "")
            + f") on {guide_levels(runs)}: "
            f"{int(attrs.get(GUIDE_ROUNDS, 0))} rounds, "
            f"{sum(runs[:-1])} runs, its own P[failure] there "
            f"{number(value(GUIDE_PROBABILITY))}"
            + ("" if int(attrs.get(GUIDE_REACHED, 0)) else " (failure region NOT reached)")
            + f"; defensive weight {number(attrs.get(GUIDE_DEFENSIVE_WEIGHT, math.nan))}",
            *finest_search_words(attrs, value(FINEST_SEARCH_INDEX)),
            *control_words(value),
            "runs per level (" + ", ".join(values) + "): " + ", ".join(map(str, runs)),
            f"plain Monte Carlo at the finest level needs "
            f"{number(value(EQUIVALENT_FINEST_RUNS))} runs for this c.o.v. (cost "
            f"{number(value(EQUIVALENT_FINEST_COST))}); both stages cost "
            f"{number(attrs.get(GUIDE_TOTAL_COST, math.nan))}: "
            f"{number(value(FINEST_COST_RATIO))} times less",
        ]
        total = int(attrs.get(SOLVER_RUNS, 0))
        return MethodReport(
            description=f"multifidelity importance sampling of '{name}', {total} runs",
            notes=notes, figures=[FigureSpec("stages", stages_figure, per_output=False)])


@dataclass
class ControlEstimate:
    """The control-variate estimate of P[failure] (``control_variate_estimate``), with the
    names of ``ImportanceEstimate``'s figures, and what it rests on."""

    probability: float
    stderr: float
    low: float
    high: float
    cov: float
    n: int                       # the pairs N
    coarse_draws: int            # the coarse draws M (the pairs' included)
    correlation: float           # rho of the finest and coarse terms over the pairs
    coefficient: float           # alpha = cov / var of the coarse terms over the pairs
    effective_sample_size: float = math.nan  # the plain estimate's (the finest weights')
    plain: object = None         # the plain estimate (ImportanceEstimate)
    left_out: int = 0            # finest runs ok whose coarse twin failed
    threshold: float = 0.0       # t of the coarse event g_c <= t


def control_variate_estimate(fine_failed, coarse_failed, log_ratio,
                             confidence: float = 0.95) -> ControlEstimate:
    """Multifidelity Monte Carlo (Peherstorfer, Willcox & Gunzburger 2016) on the weighted
    indicators of M draws u_i of q: ``coarse_failed`` (M,) the coarse event at each, ``log_ratio``
    (M,) log phi(u_i) - log q(u_i), ``fine_failed`` (N,) the finest event at the first N of
    them (N <= M). With Y_f = 1{g_f <= 0} phi/q and Y_c = 1{g_c <= 0} phi/q,

        P = mean_N(Y_f) - alpha (mean_N(Y_c) - mean_M(Y_c)),   alpha = cov(Y_f, Y_c) / var(Y_c)

    over the N pairs (unbiased for a fixed alpha; the estimated one adds a bias of order
    1 / N), and

        var P = var(Y_f) / N + (1 / N - 1 / M) (alpha^2 var(Y_c) - 2 alpha cov(Y_f, Y_c)),

    = var(Y_f) / N (1 - (1 - N / M) rho^2) at that alpha. alpha = 0 where the coarse terms do
    not vary over the pairs (no coarse failure among them): P is then the plain mean."""
    fine_failed = np.asarray(fine_failed, dtype=bool).ravel()
    coarse_failed = np.asarray(coarse_failed, dtype=bool).ravel()
    log_ratio = np.asarray(log_ratio, dtype=float).ravel()
    n, m = fine_failed.size, coarse_failed.size
    if not 2 <= n <= m == log_ratio.size:
        raise ValueError(f"need 2 <= N <= M draws with a log ratio each: N = {n}, M = {m}, "
                         f"{log_ratio.size} log ratios")
    # scaled by the largest failing term so that exp cannot overflow; the scale cancels
    failing = fine_failed | coarse_failed[:n]
    failing = np.concatenate([failing, coarse_failed[n:]])
    top = float(np.max(log_ratio[failing])) if failing.any() else 0.0
    weight = np.exp(np.where(failing, log_ratio, top) - top)
    y_fine = np.where(fine_failed, weight[:n], 0.0)
    y_coarse = np.where(coarse_failed, weight, 0.0)
    paired = y_coarse[:n]
    var_fine, var_coarse = float(np.var(y_fine, ddof=1)), float(np.var(paired, ddof=1))
    covariance = float(np.sum((y_fine - y_fine.mean()) * (paired - paired.mean())) / (n - 1))
    alpha = covariance / var_coarse if var_coarse > 0 else 0.0
    rho = covariance / math.sqrt(var_fine * var_coarse) if var_fine * var_coarse > 0 \
        else math.nan
    scale = math.exp(top)
    probability = scale * (float(y_fine.mean()) - alpha * (float(paired.mean())
                                                            - float(y_coarse.mean())))
    variance = var_fine / n + (1.0 / n - 1.0 / m) * (alpha**2 * var_coarse
                                                     - 2.0 * alpha * covariance)
    stderr = scale * math.sqrt(max(variance, 0.0))
    cov = stderr / probability if probability > 0 else math.inf
    return ControlEstimate(probability, stderr, *normal_interval(probability, stderr,
                                                                 confidence),
                           cov, n, m, rho, alpha)


def control_words(value) -> list[str]:
    """The report's line on the coarse control variate (none where it was off)."""
    plain = value(PLAIN_PROBABILITY)
    if not np.isfinite(value(CONTROL_CORRELATION)) and not np.isfinite(plain):
        return []
    pairs = int(value(CONTROL_PAIRS))
    if not pairs:
        return ["coarse control variate NOT used (fewer than 2 pairs ran ok): P[failure] "
                "is the plain estimate"]
    left = int(value(CONTROL_LEFT_OUT))
    return [f"coarse control variate: {pairs} finest runs paired with their coarse twins, "
            f"{int(value(CONTROL_COARSE_DRAWS))} coarse draws in all, correlation "
            f"{number(value(CONTROL_CORRELATION))}, alpha {number(value(CONTROL_COEFFICIENT))}"
            f" (MFMC's optimal coarse draws per finest draw at these costs: "
            f"{number(value(CONTROL_OPTIMAL_RATIO))}); without it P[failure] = "
            f"{number(plain)}, stderr {number(value(PLAIN_STDERR))}"
            + (f"; {left} finest runs left out of the pairs (coarse twin failed)" if left
               else "")]


def finest_search_words(attrs, beta: float) -> list[str]:
    """The report's line on the design point's refinement at the finest level (none where
    it did not run)."""
    rounds = int(attrs.get(FINEST_SEARCH_ROUNDS, 0))
    if not rounds:
        return []
    if not np.isfinite(beta):
        return [f"design point refined on the finest level: {rounds} round(s), NOT usable: "
                f"the biasing density stays at the coarse design point"]
    return [f"design point refined on the finest level: {rounds} round(s) of FORM's search "
            f"from the coarse design point, first-order beta there {number(beta)}; the "
            f"biasing density's centre moved "
            f"{number(float(attrs.get(FINEST_SEARCH_SHIFT, math.nan)))} from the coarse "
            f"design point"]


def guide_levels(runs: list[int]) -> str:
    """The levels stage 1 ran at, in words, from the runs per level (the finest last)."""
    used = [lv for lv, n in enumerate(runs[:-1]) if n]
    if used in ([], [0]):
        return "the coarsest level"
    return "levels " + ", ".join(map(str, used))


def stages_figure(view, output=None):
    """Where each stage drew, in the plane of the two inputs the biasing density moves most
    (standard normal units): the coarse rows of stage 1, the finest-level draws of stage 2 and
    the biasing components' means (None without two inputs or without the density)."""
    stats, runs = view.stats, view.runs
    if runs is None or BIASING_MEAN not in stats or STANDARD_NORMAL not in runs.coords or \
            runs.sizes.get(PARAMETER, 0) < 2:
        return None
    means = np.asarray(stats[BIASING_MEAN].values, dtype=float)
    axes = np.sort(np.argsort(-np.abs(means[:-1]).max(axis=0), kind="stable")[:2])
    names = [str(p) for p in runs[PARAMETER].values[axes]]
    u = np.asarray(runs[STANDARD_NORMAL].values, dtype=float)[:, axes]
    finest = np.asarray(runs[STAGE].values == STAGE_ESTIMATE)
    refining = np.asarray(runs[STAGE].values == STAGE_FINEST_SEARCH)
    # the control variate's coarse draws are q's, as stage 2's finest ones
    coarse = ~finest & ~refining & np.asarray(runs[STAGE].values != STAGE_CONTROL)
    fig, ax = new_figure(width=5.6, height=5.0)
    ax.scatter(u[coarse, 0], u[coarse, 1], s=6, color="#9e9e9e", alpha=0.6,
               label=f"stage 1, coarser level(s) ({int(coarse.sum())} runs)")
    if refining.any():
        ax.scatter(u[refining, 0], u[refining, 1], s=18, marker="^", color="#e67e22",
                   label=f"design point refined, finest level ({int(refining.sum())} runs)")
    ax.scatter(u[finest, 0], u[finest, 1], s=6, color="#1f4e79", alpha=0.6,
               label=f"stage 2, finest level ({int(finest.sum())} runs)")
    ax.scatter(means[:-1, axes[0]], means[:-1, axes[1]], marker="x", s=80, color="#c0392b",
               label="biasing density's centre(s)")
    ax.set_xlabel(f"u of {names[0]} (standard normal)")
    ax.set_ylabel(f"u of {names[1]} (standard normal)")
    ax.set_title(f"where the stages drew: P[failure of {stats.attrs.get(LIMIT_STATE, '?')}]")
    ax.legend(loc="best", fontsize="small")
    return fig


def with_defensive(density: GaussianMixture, weight: float) -> GaussianMixture:
    """(1 - weight) density + weight phi: every likelihood ratio phi / q is then at most
    1 / weight."""
    d = density.dimension
    return GaussianMixture(np.append((1.0 - weight) * density.weights, weight),
                           np.vstack([density.means, np.zeros((1, d))]),
                           np.concatenate([density.covariances, np.eye(d)[None]]))


class GuideCrossEntropy(CrossEntropy):
    """The single-level cross-entropy method's rounds (``replay_rounds``: its rules and
    families), with its Gaussian fits' eigenvalues floored at ``floor`` = min_spread^2 (the
    quantile rule's single Gaussian too): a coarse failure region narrower than the finest's
    may move the biasing density, never narrow it below the inputs' own spread."""

    floor: float = 1.0
    #: fits already made, keyed on their points, weights and family: every round replays the
    #: rounds before it, and a mixture's EM is what a replay costs
    fits: dict | None = None

    def fit(self, u, log_weights, family: str):
        key = hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in (
            np.asarray(u, dtype=float), np.asarray(log_weights, dtype=float)))
            + family.encode()).hexdigest()
        if self.fits is not None and key in self.fits:
            return self.fits[key]
        if family == "vmfn":
            fitted = fit_von_mises_fisher_nakagami(u, log_weights)
        else:
            fitted = fit_gaussian_mixture(u, log_weights, self.options.mixture_components,
                                          floor=self.floor, covariance=self.options.covariance)
        if self.fits is not None:
            if len(self.fits) >= MAX_KEPT_FITS:
                self.fits.pop(next(iter(self.fits)))
            self.fits[key] = fitted
        return fitted

    def quantile_round(self, state, u, g, log_ratio, family) -> None:
        usable = np.isfinite(g)
        threshold = max(float(np.quantile(g[usable], self.options.rho)), 0.0)
        elite = usable & (g <= threshold)
        state.density = self.fit(u[elite], log_ratio[elite], family)
        state.thresholds.append(threshold)
        state.elites.append(int(elite.sum()))
        state.effective.append(effective_count(log_ratio[elite]))
        state.fitted.append(family)
        state.reached = threshold == 0.0


@dataclass(frozen=True, eq=False)
class DefensiveMixture:
    """(1 - weight) q* + weight phi for a q* that is not a Gaussian mixture (the von
    Mises-Fisher-Nakagami density): sampling and log q, as ``GaussianMixture`` offers."""

    density: VonMisesFisherNakagami
    weight: float

    @property
    def dimension(self) -> int:
        return self.density.dimension

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` draws: which component by one uniform each, then q*'s draws, then phi's,
        all from ``rng`` (the same state gives the same draws)."""
        defensive = rng.random(int(n)) < self.weight
        out = np.empty((int(n), self.dimension))
        out[~defensive] = self.density.sample(rng, int((~defensive).sum()))
        out[defensive] = rng.standard_normal((int(defensive.sum()), self.dimension))
        return out

    def log_pdf(self, u: np.ndarray) -> np.ndarray:
        u = np.atleast_2d(np.asarray(u, dtype=float))
        return np.logaddexp(math.log1p(-self.weight) + self.density.log_pdf(u),
                            math.log(self.weight) + standard_normal_log_pdf(u))
