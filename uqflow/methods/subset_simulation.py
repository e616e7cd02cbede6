"""Subset simulation (Au & Beck 2001) with adaptive conditional sampling (Papaioannou, Betz,
Zwirglmaier & Straub 2015): small probabilities of failure as a product of larger
conditional ones.

It works in the standard normal space u of the study's inputs (the inputs' Gaussian copula,
as FORM: ``uqflow.methods.form.to_inputs``), on the margin g(u) of one limit state or system
of the study (g <= 0 failure). Level 0 draws N independent u ~ N(0, I). Each level ends at
the threshold b_j between the p0 N-th and the next smallest g; the p0 N samples below it
seed p0 N Markov chains of length 1/p0 whose states are distributed as u given g(u) <= b_j,
which make the next level's N samples. The last level is the first whose p0 N-th smallest g
is <= 0: p_f = p0^(m-1) N_f / N.

The chains move by adaptive conditional sampling: the proposal of a chain at u is
v_i ~ N(rho_i u_i, sigma_i^2) with sigma_i = min(lambda s_i, 1), rho_i = sqrt(1 - sigma_i^2)
(s_i the spread of the seeds along axis i), accepted if g(v) <= b_j, otherwise the chain
stays. lambda moves towards the acceptance rate 0.44: after every round, over groups of
chains in the seeds' order, log lambda += (a_group - 0.44) / sqrt(i).

Running as rounds: level 0 is the plan; after it, every step of all the chains of a level
is one round (``extend``): the chains' proposals run in parallel, as realizations. The state
(the thresholds, the seeds, which proposal was accepted, lambda) is replayed from the runs
alone, and the proposals' random numbers come from the study's seed spawned per
(level, step): the answer is the same for any worker count and after a resume.

The c.o.v. is the genealogical one: every state descends from one level-0 sample through
its chain's seeds, and the spread of the last level's failures over those families,
sum_r (F_r / F)^2 - 1 / N (Chan & Lai 2013; Du & Guyader 2021), estimates the relative
variance of p_f with the chains' and the levels' correlation included; with k effective
families it carries the correction k / (k - 1) and the interval a Student t quantile with
k - 1 degrees of freedom. Au & Beck's per-level delta_j^2 = (1 - p_j) / (N p_j) (1 +
gamma_j), gamma_j from the chains' indicator autocorrelation, are stored beside, summed as if
the levels were uncorrelated (a lower estimate) and as if fully correlated.
docs/subset_simulation.md.
"""

from __future__ import annotations

import math
import warnings as pywarnings
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import xarray as xr
from pydantic import Field, ValidationInfo, field_validator
from scipy import stats as sps

from uqflow import probability
from uqflow.errors import AccuracyWarning, StudyError
from uqflow.layout import (BOUND, BOUND_HIGH, BOUND_LOW, CHAIN, CHAIN_STEP, CONFIDENCE,
                           EXCEEDANCE_COMPARISON, EXCEEDANCE_INTERVAL, EXCEEDANCE_LEVEL,
                           EXCEEDANCE_NOTE, EXCEEDANCE_POINT, EXCEEDANCE_PROBABILITY,
                           EXCEEDANCE_QUANTITY, EXCEEDANCE_THRESHOLD, EXCEEDANCE_UNITS,
                           FAILURE_COV, FAILURE_COV_CORRELATED, FAILURE_COV_UNCORRELATED,
                           FAILURE_FAMILIES, FAILURE_INTERVAL,
                           FAILURE_NOTE, FAILURE_PROBABILITY, FAILURES, INTERVAL_METHOD,
                           LIMIT_STATE, PARAMETER, REALIZATION, RELIABILITY_INDEX,
                           SOLVER_RUNS, STATISTIC, STATISTIC_MEAN, STATISTIC_STD,
                           SUBSET_ACCEPTANCE, SUBSET_COV, SUBSET_FAILED_RUNS, SUBSET_GAMMA,
                           SUBSET_LEVEL, SUBSET_PROBABILITY, SUBSET_SAMPLES, SUBSET_SCALE,
                           SUBSET_THRESHOLD, UNITS, ok_mask, output_names)
from uqflow.limit_states import EXCEEDS, LimitStateSystem
from uqflow.methods.base import (MAX_REALIZATIONS, MethodOptions, PropagationMethod,
                                 finish_statistics, make_design, register_method)
from uqflow.methods.form import STANDARD_NORMAL, to_inputs
from uqflow.report import (FigureSpec, MethodReport, display_units, exceedance_log_figure,
                           number)

#: the acceptance rate aCS steers lambda to (Papaioannou et al. 2015, after Roberts &
#: Rosenthal's optimal 0.44 for one-dimensional random-walk proposals)
TARGET_ACCEPTANCE = 0.44
#: lambda of the first level (Papaioannou et al.'s recommended start); later levels start
#: from the lambda the previous one ended with
INITIAL_SCALE = 0.6
#: chain steps per adaptation of lambda, as a fraction of N: Papaioannou et al. adapt after
#: groups of p_a N_s chains of 1/p0 steps, p_a = 0.1, i.e. after 0.1 N chain steps
ADAPTATION_FRACTION = 0.1
#: a word of the proposals' spawn key, apart from the executor's per-realization keys
RNG_WORD = 0x5355


class SubsetSimulationOptions(MethodOptions):
    limit_state: str | None = Field(None, description="the study's limit state or system to "
                                    "analyse (default: its only one)")
    level_probability: float = Field(0.1, gt=0, le=0.5, description="p0: the conditional "
                                     "probability of each level's event")
    samples_per_level: int = Field(1000, ge=4, le=MAX_REALIZATIONS,
                                   description="N: samples of each level")
    max_levels: int = Field(10, ge=1, le=100, description="most levels (level 0 included); "
                            "p_f below p0^max_levels is out of reach")
    confidence: float = Field(0.95, gt=0, lt=1, description="level of the interval of p_f")

    @field_validator("samples_per_level")
    @classmethod
    def _whole_chains(cls, n, info: ValidationInfo):
        p0 = info.data.get("level_probability")
        if p0 is None:
            return n
        seeds = round(p0 * n)
        if abs(seeds - p0 * n) > 1e-9 * n or seeds < 2 or n % seeds:
            raise ValueError(f"{n} samples at level_probability {p0:g} do not make whole "
                             f"chains: p0 N = {p0 * n:g} seeds must be a whole number >= 2 "
                             f"dividing N (chains of N / (p0 N) states; e.g. p0 = 0.1 with N "
                             f"a multiple of 10, at least 20)")
        return n


@dataclass
class SubsetLevel:
    """One level as replayed: its samples' rows (level 0: in order; later: chain-major,
    chains x steps), their g, the threshold that ends it, and its diagnostics."""

    index: int
    rows: np.ndarray                 # (chains, length) row of each state; (1, N) at level 0
    g: np.ndarray                    # (chains, length) g of each state (NaN: did not run ok)
    threshold: float = math.nan      # b_{j+1}; 0 at the last level
    probability: float = math.nan    # p_j: fraction of the ok samples with g <= threshold
    gamma: float = 0.0
    acceptance: float = math.nan
    scale: float = math.nan
    failed: int = 0
    complete: bool = True

    @property
    def samples(self) -> int:
        return int(np.isfinite(self.g).sum())

    @property
    def cov(self) -> float:
        p, n = self.probability, self.samples
        if not (n and np.isfinite(p)):
            return math.nan
        if p == 0:
            return math.inf
        return math.sqrt((1 - p) / (n * p) * (1 + self.gamma))


@dataclass
class Progress:
    """The state of the simulation after the rounds so far (a pure function of them)."""

    levels: list[SubsetLevel] = field(default_factory=list)
    scale: float = INITIAL_SCALE
    #: the next round: (level, step, rows of the chains' current states, sigma, rho)
    pending: tuple | None = None
    converged: bool = False
    stopped: str = ""


def correlation_factor(indicator: np.ndarray) -> float:
    """Au & Beck's gamma of chains' indicators (chains, length): 2 sum_k (1 - k/L) rho(k),
    rho(k) the lag-k correlation of the indicator estimated over all chains."""
    chains, length = indicator.shape
    x = indicator.astype(float)
    p = x.mean()
    variance = p * (1 - p)
    if length < 2 or variance == 0:
        return 0.0
    gamma = 0.0
    for k in range(1, length):
        covariance = float((x[:, :-k] * x[:, k:]).sum()) / (chains * (length - k)) - p * p
        gamma += 2 * (1 - k / length) * covariance / variance
    return gamma


def family_roots(levels: list[SubsetLevel], realizations: int) -> list[np.ndarray]:
    """For every level, the level-0 sample (its position at level 0) each state descends
    from, in the level's (chains, length) layout (-1 where a chain has not run that far).
    A chain's proposals are its own rows, so a row has one root: its chain's seed's."""
    root_of_row = np.full(realizations, -1, dtype=np.int64)
    first = levels[0].rows.ravel()
    root_of_row[first] = np.arange(first.size)
    roots = [root_of_row[levels[0].rows]]
    for level in levels[1:]:
        chain_roots = root_of_row[level.rows[:, 0]]
        level_roots = np.where(level.rows >= 0, chain_roots[:, None], -1)
        root_of_row[level.rows[level.rows >= 0]] = level_roots[level.rows >= 0]
        roots.append(level_roots)
    return roots


@dataclass(frozen=True)
class Genealogy:
    """The c.o.v. of p_f from the failures' level-0 families (see ``genealogical_cov``)."""

    #: sqrt(sum_r (F_r / F)^2 - 1 / N), F_r the last level's failures descending from the
    #: level-0 sample r; the levels' correlation through common ancestors included
    cov_raw: float
    #: Kish's effective number of families, 1 / sum_r (F_r / F)^2
    families: float

    @property
    def cov(self) -> float:
        """cov_raw with the few-clusters correction k / (k - 1) of the variance (inf for
        k <= 1: one family carries every failure, its spread is unknown)."""
        k = self.families
        if not np.isfinite(self.cov_raw) or not k > 1:
            return math.inf
        return self.cov_raw * math.sqrt(k / (k - 1))

    @property
    def degrees_of_freedom(self) -> float:
        """k - 1, of the Student t quantile of the interval (a variance estimated from k
        families)."""
        return max(self.families - 1.0, 0.0)


def genealogical_cov(failure_roots: np.ndarray, roots: int) -> Genealogy:
    """The c.o.v. of a subset simulation's p_f from the genealogy of its final failures
    (Chan & Lai 2013's estimator for sequential Monte Carlo, which Du & Guyader 2021 show
    consistent with adaptive levels): p_f = p0^(m-1) F / N is (1/N) sum_r of the roots'
    shares, so its relative variance is estimated by sum_r (F_r / F)^2 - 1 / N over the
    ``roots`` level-0 samples. It equals Au & Beck's for one level and for two (exactly:
    the same indicators and chains), and adds what theirs leaves out with more, the levels'
    correlation through the seeds: a family that is deep in one level seeds more chains in
    the next. ``failure_roots``: the root of each failing state of the last level."""
    failures = failure_roots.size
    if failures == 0 or roots == 0:
        return Genealogy(math.inf, 0.0)
    shares = np.bincount(failure_roots, minlength=roots) / failures
    concentration = float(np.sum(shares**2))
    return Genealogy(math.sqrt(max(concentration - 1.0 / roots, 0.0)), 1.0 / concentration)


@dataclass(frozen=True)
class RunningGenealogy:
    """``genealogical_cov`` of the first i states of a level in the order given, i = 1 ..
    n, as arrays (the exceedance curve's points)."""

    cov_raw: np.ndarray
    families: np.ndarray

    @property
    def cov(self) -> np.ndarray:
        k = self.families
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(k > 1, self.cov_raw * np.sqrt(k / (k - 1)), math.inf)

    @property
    def degrees_of_freedom(self) -> np.ndarray:
        return np.maximum(self.families - 1.0, 0.0)


def running_genealogy(roots: np.ndarray, level_0_samples: int) -> RunningGenealogy:
    """``genealogical_cov`` of every prefix of ``roots`` at once: adding a state of a family
    that has c states so far raises sum_r F_r^2 by 2 c + 1."""
    n = roots.size
    by_root = np.argsort(roots, kind="stable")
    sorted_roots = roots[by_root]
    first = np.r_[0, np.flatnonzero(np.diff(sorted_roots)) + 1]
    seen_before = np.empty(n, dtype=np.int64)
    seen_before[by_root] = np.arange(n) - np.repeat(first, np.diff(np.r_[first, n]))
    squares = np.cumsum(2 * seen_before + 1).astype(float)
    count = np.arange(1, n + 1, dtype=float)
    concentration = squares / count**2
    return RunningGenealogy(np.sqrt(np.maximum(concentration - 1.0 / level_0_samples, 0.0)),
                            1.0 / concentration)


def lognormal_interval(p, cov, confidence: float, degrees_of_freedom=None) -> np.ndarray:
    """[p exp(-z s), p exp(z s)] (last axis), s^2 = ln(1 + cov^2): the interval of a
    lognormal estimate whose median is p and whose c.o.v. is cov (element-wise; NaN where p
    is not positive or either is not finite). z is the normal quantile, or Student t's with
    ``degrees_of_freedom`` (element-wise) where the c.o.v. is estimated from few independent
    groups (below 1: the interval is [0, 1])."""
    p, cov = np.broadcast_arrays(np.asarray(p, dtype=float), np.asarray(cov, dtype=float))
    if degrees_of_freedom is None:
        z = float(sps.norm.ppf(0.5 + confidence / 2))
    else:
        dof = np.asarray(degrees_of_freedom, dtype=float)
        z = np.where(dof >= 1, sps.t.ppf(0.5 + confidence / 2, np.maximum(dof, 1.0)),
                     math.inf)
    usable = np.isfinite(p) & np.isfinite(cov) & (p > 0)
    s = np.sqrt(np.log1p(np.where(usable, cov, 0.0) ** 2))
    with np.errstate(invalid="ignore"):     # z = inf with s = 0 where not usable
        low = np.where(usable, p * np.exp(-z * s), np.nan)
        high = np.where(usable, np.minimum(p * np.exp(z * s), 1.0), np.nan)
    return np.stack([low, high], axis=-1)


@register_method("subset-simulation")
class SubsetSimulation(PropagationMethod):
    """Subset simulation with adaptive conditional sampling in standard normal space."""

    Options: ClassVar = SubsetSimulationOptions
    extends = True
    uses_limit_states: ClassVar[bool] = True

    @property
    def seeds(self) -> int:
        return round(self.options.level_probability * self.options.samples_per_level)

    @property
    def length(self) -> int:
        return self.options.samples_per_level // self.seeds

    # ------------------------------------------------------------------ the limit state
    def check_limit_states(self, limit_states) -> None:
        if limit_states is None or not list(limit_states.names):
            raise StudyError(f"method '{self.name}' needs a limit state: add a "
                             f"[[limit_states]] table", key="limit_states")
        chosen = limit_states.choose(self.options.limit_state, self.name, True)
        self.limit_states = limit_states
        self.limit_state = chosen

    def margins(self, runs: xr.Dataset) -> np.ndarray:
        """g of every realization (NaN where a run did not finish ok)."""
        g = self.limit_states.margins(runs).sel({LIMIT_STATE: self.limit_state})
        return np.where(ok_mask(runs), np.asarray(g.values, dtype=float), np.nan)

    # ------------------------------------------------------------------ designs
    def plan(self, space, fields, seed):
        self.check(space, fields)
        if getattr(self, "limit_states", None) is None:
            raise StudyError(f"method '{self.name}' needs a limit state: add a "
                             f"[[limit_states]] table", key="limit_states")
        self._space = space
        self._entropy, self._spawn_key = seed.entropy, tuple(seed.spawn_key)
        n = self.options.samples_per_level
        u = self.generator(0, 0).standard_normal((n, len(space)))
        return self.rows(u, 0, np.full(n, -1), np.zeros(n, dtype=np.int64))

    def generator(self, level: int, step: int) -> np.random.Generator:
        """The random numbers of one round: the study's seed spawned by (level, step)."""
        return np.random.default_rng(np.random.SeedSequence(
            self._entropy, spawn_key=(*self._spawn_key, RNG_WORD, level, step)))

    def rows(self, u, level, chains, steps) -> xr.Dataset:
        n = u.shape[0]
        design = make_design(self._space, to_inputs(self._space, u))
        # coordinates, not data variables: everything in the runs with a realization dim
        # is taken for a solver output
        return design.assign_coords({
            STANDARD_NORMAL: ((REALIZATION, PARAMETER), u,
                              {"long_name": "point in standard normal space"}),
            SUBSET_LEVEL: (REALIZATION, np.full(n, level, dtype=np.int64)),
            CHAIN: (REALIZATION, np.asarray(chains, dtype=np.int64)),
            CHAIN_STEP: (REALIZATION, np.asarray(steps, dtype=np.int64))})

    def extend(self, design, runs):
        progress = self.replay(runs)
        if progress.pending is None:
            return None
        level, step, current, sigma, rho = progress.pending
        u = np.asarray(runs[STANDARD_NORMAL].values, dtype=float)[current]
        z = self.generator(level, step).standard_normal(u.shape)
        proposals = rho * u + sigma * z
        return self.rows(proposals, level, np.arange(len(current)),
                         np.full(len(current), step))

    # ------------------------------------------------------------------ the replay
    def replay(self, runs: xr.Dataset) -> Progress:
        """The levels, thresholds, chains and lambda after the finished rounds, computed from
        the runs alone (a resumed study asks the same questions of the same runs)."""
        g_all = self.margins(runs)
        level_of = np.asarray(runs[SUBSET_LEVEL].values)
        step_of = np.asarray(runs[CHAIN_STEP].values)
        chain_of = np.asarray(runs[CHAIN].values)
        u_all = np.asarray(runs[STANDARD_NORMAL].values, dtype=float)
        seeds = self.seeds
        progress = Progress()
        rows = np.flatnonzero(level_of == 0)[None, :]
        current = SubsetLevel(0, rows, g_all[rows], failed=int(np.isnan(g_all[rows]).sum()))
        while True:
            progress.levels.append(current)
            g = current.g.ravel()
            ok = np.isfinite(g)
            n_ok = int(ok.sum())
            if n_ok <= seeds:
                current.probability = math.nan
                progress.stopped = (f"level {current.index} has {n_ok} samples that ran ok, "
                                    f"no more than the {seeds} seeds a level needs")
                return progress
            # stable: ties keep the samples' order (level 0: realizations; later: chains)
            order = np.argsort(np.where(ok, g, np.inf), kind="stable")
            ranked = g[order]
            if ranked[seeds - 1] <= 0:
                current.threshold = 0.0
                current.probability = float(np.sum(ranked[:n_ok] <= 0)) / n_ok
                current.gamma = self.gamma_of(current)
                progress.converged = True
                return progress
            current.threshold = 0.5 * (ranked[seeds - 1] + ranked[seeds])
            # p0 N / N, unless g ties at the threshold (a discrete output): then all the tied
            # samples are in the next level's event
            current.probability = float(np.sum(ranked[:n_ok] <= current.threshold)) / n_ok
            current.gamma = self.gamma_of(current)
            stuck = current.probability >= 1.0 or len(progress.levels) > 1 and \
                current.threshold >= progress.levels[-2].threshold
            if stuck or len(progress.levels) >= self.options.max_levels:
                progress.stopped = (
                    f"the threshold stopped falling at {current.threshold:.6g} > 0 (g ties "
                    f"there: a discrete output cannot be split into levels)" if stuck else
                    f"max_levels = {self.options.max_levels} levels reached with the "
                    f"threshold still at {current.threshold:.6g} > 0")
                current.probability = float(np.sum(ranked[:n_ok] <= 0)) / n_ok
                current.gamma = self.gamma_of(current, 0.0)
                return progress
            # the chains in the order of their seeds' rows, not of their g
            seed_rows = np.sort(current.rows.ravel()[order[:seeds]])
            current = self.next_level(progress, current, seed_rows, g_all, u_all, level_of,
                                      step_of, chain_of)
            if not current.complete:
                return progress

    def next_level(self, progress, previous, seed_rows, g_all, u_all, level_of, step_of,
                   chain_of, length: int | None = None) -> SubsetLevel:
        """Level ``previous.index + 1``: its chains from ``seed_rows`` as far as they ran;
        ``progress.pending`` names the next round if they have not finished. ``length``:
        states per chain, the seed included (default N / (p0 N))."""
        index, threshold = previous.index + 1, previous.threshold
        length = self.length if length is None else length
        chains = seed_rows.size
        states = np.full((chains, length), -1, dtype=np.int64)
        states[:, 0] = seed_rows
        spread = u_all[seed_rows].std(axis=0, ddof=1)
        group = max(1, min(chains, round(ADAPTATION_FRACTION *
                                         self.options.samples_per_level)))
        adaptations, accepted_total, proposed, failed = 0, 0, 0, 0
        level = SubsetLevel(index, states, np.full((chains, length), np.nan))
        for step in range(1, length):
            sigma = np.minimum(progress.scale * spread, 1.0)
            rows = np.flatnonzero((level_of == index) & (step_of == step))
            if rows.size == 0:
                level.complete = False
                progress.pending = (index, step, states[:, step - 1], sigma,
                                    np.sqrt(1.0 - sigma**2))
                break
            if not np.array_equal(chain_of[rows], np.arange(chains)):
                raise StudyError(f"the runs of subset level {index}, step {step} are not one "
                                 f"proposal per chain in chain order: another uqflow "
                                 f"version? (use --force to start again)", key="output.path")
            g = g_all[rows]
            failed += int(np.isnan(g).sum())
            with np.errstate(invalid="ignore"):
                accepted = np.isfinite(g) & (g <= threshold)
            states[:, step] = np.where(accepted, rows, states[:, step - 1])
            accepted_total += int(accepted.sum())
            proposed += chains
            for start in range(0, chains, group):
                adaptations += 1
                rate = float(accepted[start:start + group].mean())
                progress.scale = math.exp(math.log(progress.scale) +
                                          (rate - TARGET_ACCEPTANCE) / math.sqrt(adaptations))
        filled = states >= 0
        level.g[filled] = g_all[states[filled]]
        level.acceptance = accepted_total / proposed if proposed else math.nan
        level.scale = progress.scale
        level.failed = failed
        return level

    @staticmethod
    def genealogy(levels: list[SubsetLevel], realizations: int) -> Genealogy:
        """``genealogical_cov`` of the last level's failures (g <= 0) over the level-0
        samples that ran ok."""
        if not levels:
            return Genealogy(math.nan, 0.0)
        last = levels[-1]
        with np.errstate(invalid="ignore"):
            failing = np.isfinite(last.g) & (last.g <= 0)
        roots = family_roots(levels, realizations)[-1]
        return genealogical_cov(roots[failing], levels[0].samples)

    def gamma_of(self, level: SubsetLevel, threshold: float | None = None) -> float:
        """gamma of a level's chains for the indicator g <= its threshold (0 at level 0, whose
        samples are independent)."""
        if level.index == 0:
            return 0.0
        b = level.threshold if threshold is None else threshold
        with np.errstate(invalid="ignore"):
            return correlation_factor(level.g <= b)

    # ------------------------------------------------------------------ statistics
    def analyze(self, design, runs):
        progress = self.replay(runs)
        opts = self.options
        levels = progress.levels
        warnings = self.failure_notes(levels)
        probabilities = np.array([lv.probability for lv in levels])
        covs = np.array([lv.cov for lv in levels])
        p_f = float(np.prod(probabilities)) if levels else math.nan
        cov_uncorrelated = float(math.sqrt(np.sum(covs**2))) if levels else math.nan
        cov_correlated = float(np.sum(covs)) if levels else math.nan
        genealogy = self.genealogy(levels, runs.sizes[REALIZATION])
        cov = genealogy.cov
        if p_f == 0:
            cov = cov_uncorrelated = cov_correlated = math.inf
        low, high = map(float, lognormal_interval(p_f, cov, opts.confidence,
                                                  genealogy.degrees_of_freedom))
        if not progress.converged:
            warnings.append(f"subset simulation did not reach the failure domain "
                            f"({progress.stopped}): p_f is the fraction of failures at the "
                            f"last level times the levels' probabilities, and cannot be "
                            f"trusted" + ("; no failure was seen" if p_f == 0 else ""))
        n_levels = len(levels)
        state = self.limit_states[self.limit_state]
        data = {
            FAILURE_PROBABILITY: ((LIMIT_STATE,), [p_f], {
                "long_name": "probability of failure, p0^(m-1) N_f / N", UNITS: "1"}),
            FAILURE_INTERVAL: ((LIMIT_STATE, BOUND), [[low, high]], {
                "long_name": f"{100 * opts.confidence:g} % interval of p_f (lognormal with "
                             f"the genealogical c.o.v., Student t quantile)", UNITS: "1"}),
            FAILURE_COV: ((LIMIT_STATE,), [cov], {
                "long_name": "c.o.v. of p_f from the failures' level-0 families "
                             "(genealogical, levels' correlation included)", UNITS: "1"}),
            FAILURE_FAMILIES: ((LIMIT_STATE,), [genealogy.families], {
                "long_name": "effective number of level-0 families of the last level's "
                             "failures (Kish); the interval's t has one fewer degrees of "
                             "freedom", UNITS: "1"}),
            FAILURE_COV_UNCORRELATED: ((LIMIT_STATE,), [cov_uncorrelated], {
                "long_name": "c.o.v. of p_f, levels uncorrelated (Au & Beck)", UNITS: "1"}),
            FAILURE_COV_CORRELATED: ((LIMIT_STATE,), [cov_correlated], {
                "long_name": "c.o.v. of p_f, levels fully correlated", UNITS: "1"}),
            RELIABILITY_INDEX: ((LIMIT_STATE,), [probability.reliability_index(p_f)], {
                "long_name": "reliability index beta = -Phi^-1(p_f)", UNITS: "1"}),
            FAILURES: ((LIMIT_STATE,), np.array([int(np.sum(levels[-1].g <= 0))
                                                 if progress.converged else 0]), {
                "long_name": "failures among the last level's samples"}),
            SUBSET_THRESHOLD: ((SUBSET_LEVEL,), [lv.threshold for lv in levels], {
                "long_name": "threshold of g ending the level (0 at the last)"}),
            SUBSET_PROBABILITY: ((SUBSET_LEVEL,), probabilities, {
                "long_name": "conditional probability of the next level's event",
                UNITS: "1"}),
            SUBSET_GAMMA: ((SUBSET_LEVEL,), [lv.gamma for lv in levels], {
                "long_name": "correlation factor gamma of the level's chains", UNITS: "1"}),
            SUBSET_ACCEPTANCE: ((SUBSET_LEVEL,), [lv.acceptance for lv in levels], {
                "long_name": "acceptance rate of the level's proposals", UNITS: "1"}),
            SUBSET_SCALE: ((SUBSET_LEVEL,), [lv.scale for lv in levels], {
                "long_name": "aCS scale lambda at the end of the level", UNITS: "1"}),
            SUBSET_COV: ((SUBSET_LEVEL,), covs, {
                "long_name": "c.o.v. delta_j of the level's probability", UNITS: "1"}),
            SUBSET_SAMPLES: ((SUBSET_LEVEL,), np.array([lv.samples for lv in levels]), {
                "long_name": "samples of the level that ran ok"}),
            SUBSET_FAILED_RUNS: ((SUBSET_LEVEL,), np.array([lv.failed for lv in levels]), {
                "long_name": "runs of the level that did not finish ok (level 0: samples "
                             "left out; later: proposals rejected)"}),
        }
        data.update(self.exceedance(levels, state, opts.confidence,
                                    runs.sizes[REALIZATION]))
        stats = xr.Dataset(data, coords={LIMIT_STATE: [self.limit_state],
                                         BOUND: [BOUND_LOW, BOUND_HIGH],
                                         SUBSET_LEVEL: np.arange(n_levels)})
        first = np.flatnonzero(np.asarray(runs[SUBSET_LEVEL].values) == 0)
        ok = ok_mask(runs)[first]
        for out in output_names(runs):
            values = np.asarray(runs[out].values, dtype=float)[first][ok]
            with pywarnings.catch_warnings():
                pywarnings.simplefilter("ignore", RuntimeWarning)  # no ok run: NaN
                summary = np.stack([values.mean(axis=0), values.std(axis=0, ddof=1)])
            stats[out] = xr.DataArray(summary, dims=(STATISTIC, *runs[out].dims[1:]),
                                      attrs={"long_name": f"{out}: mean and std of the level-0 "
                                                          f"samples (draws of the inputs)"})
        stats = stats.assign_coords({STATISTIC: [STATISTIC_MEAN, STATISTIC_STD]})
        stats = stats.assign_coords({d: runs[d] for d in runs.coords
                                     if d not in (REALIZATION, PARAMETER) and d in stats.dims})
        for message in warnings:
            pywarnings.warn(message, AccuracyWarning, stacklevel=2)
        stats = finish_statistics(stats, design, runs, self.name, warnings)
        stats.attrs[LIMIT_STATE] = self.limit_state
        stats.attrs.update({
            "limit_state_event": state.describe(), "converged": int(progress.converged),
            "stop_reason": progress.stopped, CONFIDENCE: opts.confidence,
            "level_probability_p0": opts.level_probability,
            "samples_per_level": opts.samples_per_level,
            INTERVAL_METHOD: "lognormal from the genealogical c.o.v., Student t quantile "
                             "with the effective families - 1 degrees of freedom",
            EXCEEDANCE_NOTE: ("Au & Beck's construction: each level's samples above its "
                              "threshold at p_0 ... p_(j-1) times their rank among the level's "
                              "samples; pointwise band lognormal with the genealogical c.o.v. "
                              "of the level's samples up to the point (Student t), p_f's "
                              "interval at p_f"),
            FAILURE_NOTE: (f"subset simulation, {n_levels} levels of "
                           f"{opts.samples_per_level} samples, p0 = "
                           f"{opts.level_probability:g}; p_f = product of the levels' "
                           f"conditional probabilities; c.o.v. from the spread of the last "
                           f"level's failures over the level-0 samples they descend from "
                           f"({genealogy.families:.3g} effective families), which counts "
                           f"the levels' correlation through the seeds (Au & Beck's, levels "
                           f"uncorrelated: {cov_uncorrelated:.3g}; fully correlated: "
                           f"{cov_correlated:.3g}); {100 * opts.confidence:g} % interval "
                           f"lognormal with median p_f and a Student t quantile")})
        return stats

    @staticmethod
    def failure_notes(levels) -> list[str]:
        notes = []
        if levels and levels[0].failed:
            notes.append(f"{levels[0].failed} of {levels[0].g.size} level-0 samples did not "
                         f"run ok: neither failure nor safe, left out of the level's N (p_f "
                         f"is biased if solver errors depend on the inputs)")
        rejected = sum(lv.failed for lv in levels[1:])
        if rejected:
            notes.append(f"{rejected} proposals of the Markov chains did not run ok: each was "
                         f"rejected (its chain stayed), so the chains sample the failure "
                         f"domain without the region where the solver fails")
        return notes

    def exceedance(self, levels, state, confidence, realizations: int) -> dict:
        """P[g <= b] over the levels (Au & Beck's construction): the samples of level j
        above its threshold, each at p_0 ... p_{j-1} times its rank among the level's N; each
        point's band from the genealogy of the level's samples up to it, as p_f's (at p_f
        it is p_f's interval); the curve of the output y for a single limit state."""
        margins, fractions, covs, freedoms = [], [], [], []
        roots_of = family_roots(levels, realizations) if levels else []
        prefix = 1.0
        for k, level in enumerate(levels):
            finite = np.isfinite(level.g)
            order = np.argsort(level.g[finite], kind="stable")
            g, roots = level.g[finite][order], roots_of[k][finite][order]
            n = g.size
            if n == 0:
                break
            last = k == len(levels) - 1
            rank = np.arange(1, n + 1)
            keep = np.ones(n, bool) if last else g > level.threshold
            genealogy = running_genealogy(roots, levels[0].samples)
            margins.append(g[keep])
            fractions.append(prefix * rank[keep] / n)
            covs.append(genealogy.cov[keep])
            freedoms.append(genealogy.degrees_of_freedom[keep])
            prefix *= level.probability
        g = np.concatenate(margins) if margins else np.zeros(0)
        p = np.concatenate(fractions) if fractions else np.zeros(0)
        cov = np.concatenate(covs) if covs else np.zeros(0)
        dof = np.concatenate(freedoms) if freedoms else np.zeros(0)
        order = np.argsort(g, kind="stable")
        g, p, cov, dof = g[order], p[order], cov[order], dof[order]
        bounds = lognormal_interval(p, cov, confidence, dof).reshape(-1, 2)
        if isinstance(state, LimitStateSystem):
            level, comparison, quantity = g, "<=", f"margin g of the {state.kind} system"
            threshold, units = 0.0, ""
        else:
            exceeds = state.comparison == EXCEEDS
            level = state.threshold - g if exceeds else state.threshold + g
            comparison = ">=" if exceeds else "<="
            quantity, threshold, units = state.reduce.describe(state.output), \
                state.threshold, state.units
            if exceeds:  # levels increasing: P[Y >= y] falls as y rises
                level, p, bounds = level[::-1], p[::-1], bounds[::-1]
        return {
            EXCEEDANCE_LEVEL: ((LIMIT_STATE, EXCEEDANCE_POINT), [level], {
                "long_name": "level y of the curve", UNITS: units}),
            EXCEEDANCE_PROBABILITY: ((LIMIT_STATE, EXCEEDANCE_POINT), [p], {
                "long_name": f"P[Y {comparison} y]", UNITS: "1"}),
            EXCEEDANCE_INTERVAL: ((LIMIT_STATE, EXCEEDANCE_POINT, BOUND), [bounds], {
                "long_name": "pointwise interval (lognormal with the genealogical c.o.v. "
                             "of the level's samples up to the point, Student t)",
                UNITS: "1"}),
            EXCEEDANCE_QUANTITY: ((LIMIT_STATE,), [quantity]),
            EXCEEDANCE_COMPARISON: ((LIMIT_STATE,), [comparison]),
            EXCEEDANCE_THRESHOLD: ((LIMIT_STATE,), [threshold]),
            EXCEEDANCE_UNITS: ((LIMIT_STATE,), [units]),
        }

    # ------------------------------------------------------------------ report
    @classmethod
    def report(cls, view):
        """p_f, its interval, c.o.v. and beta, the levels table, the notes, and the figure of
        the levels on the exceedance curve."""
        stats = view.stats
        attrs = stats.attrs
        name = str(attrs.get(LIMIT_STATE, "?"))
        runs = int(attrs.get(SOLVER_RUNS, 0))
        notes = []
        if FAILURE_PROBABILITY in stats:
            level = f"{100 * float(attrs.get(CONFIDENCE, 0.95)):g} %"
            low, high = stats[FAILURE_INTERVAL].values[0]
            event = f" ({attrs['limit_state_event']})" if attrs.get("limit_state_event") \
                else ""
            notes.append(
                f"subset simulation, limit state '{name}'{event}: p_f = "
                f"{number(float(stats[FAILURE_PROBABILITY].values[0]))} ({level} interval "
                f"{number(low)} .. {number(high)}, lognormal), c.o.v. "
                f"{number(float(stats[FAILURE_COV].values[0]))} (from the failures' "
                f"{number(float(stats[FAILURE_FAMILIES].values[0]))} effective level-0 "
                f"families; Au & Beck's, levels uncorrelated, "
                f"{number(float(stats[FAILURE_COV_UNCORRELATED].values[0]))}; fully "
                f"correlated {number(float(stats[FAILURE_COV_CORRELATED].values[0]))}), "
                f"beta = {number(float(stats[RELIABILITY_INDEX].values[0]))}"
                + ("" if int(attrs.get("converged", 0)) else
                   f" (NOT converged: {attrs.get('stop_reason', '')})"))
            notes.append("level  threshold b      P[next | level]  gamma    acceptance  "
                         "c.o.v.   ok samples  failed runs")
            for j in range(stats.sizes.get(SUBSET_LEVEL, 0)):
                def cell(var, width):
                    return number(float(stats[var].values[j])).ljust(width)
                notes.append(f"{j:<6d} {cell(SUBSET_THRESHOLD, 16)} "
                             f"{cell(SUBSET_PROBABILITY, 16)} {cell(SUBSET_GAMMA, 8)} "
                             f"{cell(SUBSET_ACCEPTANCE, 11)} {cell(SUBSET_COV, 8)} "
                             f"{int(stats[SUBSET_SAMPLES].values[j]):<11d} "
                             f"{int(stats[SUBSET_FAILED_RUNS].values[j])}")
        if attrs.get(FAILURE_NOTE):
            notes.append(f"p_f: {attrs[FAILURE_NOTE]}")
        return MethodReport(
            description=f"subset simulation of '{name}', {runs} run{'' if runs == 1 else 's'}",
            runs_are_draws=False, notes=notes,
            figures=[FigureSpec("subset_levels", levels_figure, per_output=False)])


def levels_figure(view, output=None):
    """The exceedance curve on a log scale with its pointwise band, p_f at the threshold
    (``exceedance_log_figure``), and each level's threshold marked where the next level's
    probability p_0 ... p_j starts."""
    stats = view.stats
    if EXCEEDANCE_PROBABILITY not in stats or SUBSET_THRESHOLD not in stats:
        return None
    y = np.asarray(stats[EXCEEDANCE_LEVEL].values[0], dtype=float)
    band = np.asarray(stats[EXCEEDANCE_INTERVAL].values[0], dtype=float)
    comparison = str(stats[EXCEEDANCE_COMPARISON].values[0])
    threshold = float(stats[EXCEEDANCE_THRESHOLD].values[0])
    units = str(stats[EXCEEDANCE_UNITS].values[0])
    level = f"{100 * float(stats.attrs.get(CONFIDENCE, 0.95)):g} %"
    fig = exceedance_log_figure(
        y, stats[EXCEEDANCE_PROBABILITY].values[0], band[:, 0], band[:, 1],
        threshold=threshold, failure_probability=float(stats[FAILURE_PROBABILITY].values[0]),
        failure_interval=stats[FAILURE_INTERVAL].values[0], comparison=comparison,
        name=str(stats[EXCEEDANCE_QUANTITY].values[0]), units=units,
        curve_label="subset levels: p_0 ... p_(j-1) x the level's fraction",
        band_label=f"{level} pointwise band (lognormal, genealogical c.o.v.)",
        title=f"{view.study}: subset levels of '{stats.attrs.get(LIMIT_STATE, '')}'\n"
              f"({view.description})")
    if fig is None:
        return None
    ax = fig.axes[0]
    scale, _ = display_units(np.append(y, threshold), units)
    # a level's threshold b of g is y = t - b (exceeds: P[Y >= y]) or t + b (below, and a
    # system's margin, whose threshold is 0)
    sign = -1.0 if comparison == ">=" else 1.0
    reached = np.cumprod(stats[SUBSET_PROBABILITY].values)[:-1]
    for j, (b, q) in enumerate(zip(stats[SUBSET_THRESHOLD].values[:-1], reached)):
        x = (threshold + sign * b) * scale
        ax.axvline(x, color="#7f7f7f", linestyle=":", linewidth=1)
        ax.plot([x], [q], marker="s", color="#e08e2b", linestyle="none",
                label="level thresholds b_j at p_0 ... p_j" if j == 0 else None)
    ax.legend(loc="best", fontsize="small")
    return fig
