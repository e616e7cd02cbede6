"""Multilevel subset simulation (Ullmann & Papaioannou 2015, "Multilevel estimation of rare
events", SIAM/ASA J. Uncertainty Quantification 3:922-953): subset simulation whose early,
broad subsets run on the coarse levels of the study's ``[levels]`` and only the last ones on
the finest.

The sequence of subsets D_0, D_1, ... is that of ``subset-simulation`` (each threshold b_k
the p0 quantile of the previous samples' margins, 0 at the last), but subset k is defined on
a fidelity level l(k), non-decreasing: D_k = {g_l(k) <= b_k}. A level's subsets end when its
threshold reaches 0 (its own failure domain) or after ``subsets_per_level`` of them; the
finest level's go on to its failure domain. Where two consecutive subsets are on the same
level they are nested, as in subset simulation; where the level changes they are not, and
the ratio P(D_k) / P(D_k-1) is written through Bayes' rule as

    P(D_k | D_k-1) / P(D_k-1 | D_k),

so P_L = prod_k P(D_k | D_k-1) / prod_(level changes) P(D_k-1 | D_k). The numerator is the
fraction of the samples of D_k-1 (generated at level l(k-1)) whose margin at the new level
l(k), from the "update" runs, is <= b_k; the correction in the denominator is the fraction
of samples of D_k (generated at level l(k)) inside D_k-1, from "check" runs of those samples
at the old level. The samples of D_k come from Markov chains started at the seeds in
D_k-1 and D_k; these are distributed as phi given both events, not as phi given D_k, so at a
level change every chain first runs ``burn_in`` steps that are thrown away (Ullmann &
Papaioannou's burn-in): a chain that has not forgotten its start overestimates
P(D_k-1 | D_k) and the estimate falls low (docs/rare_events_across_levels.md gives the
numbers). There the chains are fewer and longer, N // burn_in of them keeping about
burn_in states each, so the burn-in costs about N runs at the new level rather than
burn_in p0 N. Within a level the seeds are distributed as the next subset's target by
construction and no burn-in is needed.

Chains move by subset simulation's adaptive conditional sampling
(``SubsetSimulation.next_level``). Rounds (``extend``): every chain step of all chains is
one round; the update and check runs of a level change one round after the chains. The state
is replayed from the runs alone; the proposals' random numbers come from the plan's
SeedSequence spawned per (fidelity level, subset, step); rows that re-run a point at another
level carry its ``seed_key``. So the answer is the same for any worker count and after a
resume.

The c.o.v. is the genealogical one, carried over from ``subset-simulation``: every sample
of every fraction and correction descends from one first-subset draw r through its chain's
seeds (at a level change the seeds drawn at random, the re-runs being the same points), and
with N_kr, A_kr (M_kr, C_kr) the samples of fraction k (of a correction) from family r and
those of them counted in its numerator, r moves ln p_f by

    psi_r = sum_k (A_kr / A_k - N_kr / N_k) - sum_changes (C_kr / C_k - M_kr / M_k);

the families are independent, so the relative variance is sum_r psi_r^2 (delta method).
Within a level the seeds' share of a family is its previous hits' share, psi_r telescopes to
F_r / F - 1 / N and this is subset simulation's estimator exactly; across a level change it
counts what Au & Beck's uncorrelated sum leaves out, the subsets' correlation through the
seeds and a correction's with its fraction (``influence_genealogy``). With k effective
families (Kish, of the last fraction's failures) the variance carries k / (k - 1) and the
interval a Student t quantile with k - 1 degrees of freedom, as in ``subset-simulation``.
Au & Beck's delta^2 = (1 - p) / (M p) (1 + gamma) of every fraction and correction are
stored beside, summed as uncorrelated and as fully correlated. Cost: runs per level, the
equivalent plain Monte Carlo at the finest level for the same c.o.v. as
``multifidelity-importance-sampling`` reports it.
"""

from __future__ import annotations

import math
import warnings as pywarnings
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np
import xarray as xr
from pydantic import Field, model_validator

from uqflow import probability
from uqflow.errors import AccuracyWarning, StudyError
from uqflow.layout import (BOUND, BOUND_HIGH, BOUND_LOW, CHAIN, CHAIN_STEP, CONFIDENCE,
                           EQUIVALENT_FINEST_COST, EQUIVALENT_FINEST_RUNS, FAILURE_COV,
                           FAILURE_COV_CORRELATED, FAILURE_COV_UNCORRELATED,
                           FAILURE_FAMILIES, FAILURE_INTERVAL, FAILURE_NOTE,
                           FAILURE_PROBABILITY, FAILURES, FIDELITY_COST, FIDELITY_RUNS,
                           FIDELITY_VALUE, FINEST_COST_RATIO, INTERVAL_METHOD, LEVEL,
                           LIMIT_STATE, MULTILEVEL_TOTAL_COST, PARAMETER, REALIZATION,
                           RELIABILITY_INDEX, SEED_KEY, SOLVER_RUNS, STATUS, STATUS_PENDING,
                           SUBSET_ACCEPTANCE, SUBSET_BURN_IN, SUBSET_CORRECTION,
                           SUBSET_CORRECTION_COV, SUBSET_COV, SUBSET_FIDELITY, SUBSET_GAMMA,
                           SUBSET_LEVEL, SUBSET_PROBABILITY, SUBSET_SAMPLES, SUBSET_SCALE,
                           SUBSET_THRESHOLD, STATISTIC, STATISTIC_MEAN, STATISTIC_STD, UNITS,
                           ok_mask, output_names)
from uqflow.methods.base import finish_statistics, make_design, register_method
from uqflow.methods.fidelity_sampling import MAX_COST
from uqflow.methods.form import STAGE, STANDARD_NORMAL, to_inputs
from uqflow.methods.multifidelity_reliability import MultifidelityImportanceSampling
from uqflow.methods.subset_simulation import (INITIAL_SCALE, Genealogy, SubsetLevel,
                                              SubsetSimulation, SubsetSimulationOptions,
                                              correlation_factor, family_roots,
                                              genealogical_cov, lognormal_interval)
from uqflow.report import FigureSpec, MethodReport, new_figure, number

#: what a row is: a first-subset draw, a chain's proposal, a sample re-run at the next level
#: (update), or a sample of the new subset re-run at the previous level (check)
STAGE_DRAW, STAGE_CHAIN, STAGE_UPDATE, STAGE_CHECK = "draw", "chain", "update", "check"
#: the kind of a pending round of update and check runs
RERUN = "rerun"
#: a word of the proposals' spawn key, apart from subset-simulation's and the executor's
RNG_WORD = 0x4D4C
#: burn-in steps per chain at a level change: twice the 20 that brought the correction
#: within its standard error of the exact one on the tests' narrow coarse level (10 left
#: it 18 % high, none 73 %), a margin for slower-mixing families
#: (docs/rare_events_across_levels.md)
DEFAULT_BURN_IN = 40


class MultilevelSubsetOptions(SubsetSimulationOptions):
    burn_in: int = Field(DEFAULT_BURN_IN, ge=0, le=10_000, description="Markov chain steps "
                         "thrown away per chain at each level change, before its samples")
    subsets_per_level: list[int] | None = Field(
        None, description="most subsets on each level but the finest, coarsest first "
                          "(default: each level's subsets go on to its failure domain)")
    costs: Literal["measured"] | list[float] = Field(
        "measured", description="cost of one run per level, coarsest first: 'measured' "
                                "(median wall time less compile time) or numbers")

    @model_validator(mode="after")
    def _counts(self):
        if self.subsets_per_level is not None and not all(
                1 <= n <= self.max_levels for n in self.subsets_per_level):
            raise ValueError(f"subsets_per_level must be between 1 and max_levels = "
                             f"{self.max_levels} each, got {self.subsets_per_level}")
        if isinstance(self.costs, list) and not all(0 < c <= MAX_COST for c in self.costs):
            raise ValueError(f"every cost must be > 0 and <= {MAX_COST:.2g} (costs are "
                             f"relative, any unit), got {self.costs}")
        return self


@dataclass
class Subset:
    """One subset as replayed: its samples (chains x length point rows, and their margin at
    its own fidelity level), its threshold and fraction, and at a level change the
    correction P(previous event | this one)."""

    index: int
    level: int
    points: np.ndarray
    g: np.ndarray
    changed: bool = False
    threshold: float = math.nan
    probability: float = math.nan
    gamma: float = 0.0
    acceptance: float = math.nan
    scale: float = math.nan
    correction: float = 1.0
    correction_cov: float = 0.0
    on_level: int = 1                # its rank among the subsets of its level, from 1
    #: the samples counted in the fraction's numerator (g <= the threshold it is taken at)
    hits: np.ndarray | None = None
    #: the chains run from its seeds, (chains, burn + kept) rows with the seed first: the
    #: next subset's samples are their kept states [:, burn:]
    chain_rows: np.ndarray | None = None
    burn: int = 0
    #: at a level change, those kept states' margins at the previous subset's level (the
    #: correction's samples)
    check_g: np.ndarray | None = None

    @property
    def samples(self) -> int:
        return int(np.isfinite(self.g).sum())

    @property
    def cov(self) -> float:
        p, n = self.probability, self.samples
        if not (n and np.isfinite(p)):
            return math.nan
        return math.inf if p == 0 else math.sqrt((1 - p) / (n * p) * (1 + self.gamma))


@dataclass
class Replay:
    subsets: list[Subset] = field(default_factory=list)
    scale: float = INITIAL_SCALE
    pending: tuple | None = None     # (kind, ...) of the next round
    converged: bool = False
    stopped: str = ""


def influence_genealogy(fractions, corrections, roots: int) -> Genealogy:
    """The c.o.v. of p_f = prod_k A_k / N_k / prod_changes C_k / M_k from the level-0
    families of all its samples (docs/rare_events_across_levels.md, "The genealogical
    c.o.v."). ``fractions`` and ``corrections``: one (sample_roots, inside) pair per ratio,
    the level-0 family of each of its samples that ran ok and whether it is counted in the
    numerator. Each family r moves ln p_f by its influence

        psi_r = sum_k (A_kr / A_k - N_kr / N_k) - sum_changes (C_kr / C_k - M_kr / M_k),

    the families are independent, so the relative variance is sum_r psi_r^2 (delta
    method). Within one level the seeds' share of a family is its previous hits' share and
    psi_r telescopes to F_r / F - 1 / N: subset simulation's ``genealogical_cov``. Kish's
    effective families are those of the last fraction's hits, as there."""
    influence = np.zeros(roots)
    for sign, ratios in ((1.0, fractions), (-1.0, corrections)):
        for sample_roots, inside in ratios:
            hits = sample_roots[inside]
            if hits.size == 0:
                return Genealogy(math.inf, 0.0)
            influence += sign * (np.bincount(hits, minlength=roots) / hits.size -
                                 np.bincount(sample_roots, minlength=roots) /
                                 sample_roots.size)
    last_roots, last_inside = fractions[-1]
    families = genealogical_cov(last_roots[last_inside], roots).families
    return Genealogy(math.sqrt(float(np.sum(influence**2))), families)


@register_method("multilevel-subset-simulation")
class MultilevelSubsetSimulation(SubsetSimulation):
    """Subset simulation across fidelity levels with Bayes' correction at level changes."""

    Options: ClassVar = MultilevelSubsetOptions
    uses_levels: ClassVar[bool] = True

    def check_levels(self, levels) -> None:
        self.n_levels = len(levels)
        self.level_values = [float(v) for v in levels.values]
        opts = self.options
        if isinstance(opts.costs, list) and len(opts.costs) != self.n_levels:
            raise StudyError(f"costs has {len(opts.costs)} values for {self.n_levels} levels",
                             key="method.costs")
        if opts.subsets_per_level is not None and \
                len(opts.subsets_per_level) != self.n_levels - 1:
            raise StudyError(f"subsets_per_level has {len(opts.subsets_per_level)} values "
                             f"for the {self.n_levels - 1} levels below the finest",
                             key="method.subsets_per_level")

    # ------------------------------------------------------------------ designs
    def plan(self, space, fields, seed):
        self.check(space, fields)
        if getattr(self, "limit_states", None) is None:
            raise StudyError(f"method '{self.name}' needs a limit state: add a "
                             f"[[limit_states]] table", key="limit_states")
        if not hasattr(self, "n_levels"):
            raise StudyError(f"method '{self.name}' needs the study's [levels]", key="levels")
        self._space = space
        self._entropy, self._spawn_key = seed.entropy, tuple(seed.spawn_key)
        n = self.options.samples_per_level
        u = self.draws(0, 0, 0).standard_normal((n, len(space)))
        return self.level_rows(u, STAGE_DRAW, 0, 0, np.full(n, -1), np.zeros(n, np.int64),
                               np.arange(n))

    def draws(self, level: int, subset: int, step: int) -> np.random.Generator:
        """The random numbers of one round: the study's seed spawned by (level, subset,
        step)."""
        return np.random.default_rng(np.random.SeedSequence(
            self._entropy, spawn_key=(*self._spawn_key, RNG_WORD, level, subset, step)))

    def level_rows(self, u, stage, subset, level, chains, steps, keys) -> xr.Dataset:
        """Rows of ``stage`` at fidelity ``level`` (one each, or one per row); ``keys`` the
        seed_key of each: the row of the point it runs (its own row for a new point). The
        coordinates of subset simulation's rows, and ``stage``."""
        n = u.shape[0]

        def each(value, dtype):
            return np.broadcast_to(np.asarray(value, dtype=dtype), (n,)).copy()
        design = make_design(self._space, to_inputs(self._space, u), **{
            LEVEL: (REALIZATION, each(level, np.int64)),
            SEED_KEY: (REALIZATION, np.asarray(keys, dtype=np.int64))})
        # coordinates, not data variables: everything in the runs with a realization dim
        # is taken for a solver output
        return design.assign_coords({
            STANDARD_NORMAL: ((REALIZATION, PARAMETER), u,
                              {"long_name": "point in standard normal space"}),
            SUBSET_LEVEL: (REALIZATION, each(subset, np.int64)),
            CHAIN: (REALIZATION, np.asarray(chains, dtype=np.int64)),
            CHAIN_STEP: (REALIZATION, np.asarray(steps, dtype=np.int64)),
            STAGE: (REALIZATION, each(stage, object))})

    def extend(self, design, runs):
        replay = self.replay(runs)
        if replay.pending is None:
            return None
        n_runs = runs.sizes[REALIZATION]
        u_all = np.asarray(runs[STANDARD_NORMAL].values, dtype=float)
        if replay.pending[0] == STAGE_CHAIN:
            _, level, subset, (_, step, current, sigma, rho) = replay.pending
            z = self.draws(level, subset, step).standard_normal((len(current), u_all.shape[1]))
            proposals = rho * u_all[current] + sigma * z
            return self.level_rows(proposals, STAGE_CHAIN, subset, level,
                                   np.arange(len(current)), np.full(len(current), step),
                                   np.arange(n_runs, n_runs + len(current)))
        _, subset, reruns = replay.pending
        keys = np.asarray(runs[SEED_KEY].values)
        points = np.concatenate([rows for _, _, rows in reruns])
        stages = np.concatenate([np.full(rows.size, kind, dtype=object)
                                 for kind, _, rows in reruns])
        levels = np.concatenate([np.full(rows.size, lv) for _, lv, rows in reruns])
        return self.level_rows(u_all[points], stages, subset, levels,
                               np.full(points.size, -1), np.zeros(points.size, np.int64),
                               keys[points])

    # ------------------------------------------------------------------ the replay
    def last_subset_on(self, level: int) -> int:
        per_level = self.options.subsets_per_level
        if level == self.n_levels - 1 or per_level is None:
            return self.options.max_levels
        return per_level[level]

    def replay(self, runs: xr.Dataset) -> Replay:
        """The subsets, thresholds, chains and corrections after the finished rounds,
        computed from the runs alone."""
        g_all = self.margins(runs)
        stage = np.asarray(runs[STAGE].values)
        subset_of = np.asarray(runs[SUBSET_LEVEL].values)
        step_of = np.where(stage == STAGE_CHAIN, np.asarray(runs[CHAIN_STEP].values), -1)
        chain_of = np.asarray(runs[CHAIN].values)
        keys = np.asarray(runs[SEED_KEY].values)
        u_all = np.asarray(runs[STANDARD_NORMAL].values, dtype=float)
        seeds, burn_in = self.seeds, self.options.burn_in
        replay = Replay()
        rows = np.flatnonzero(stage == STAGE_DRAW)[None, :]
        current = Subset(0, 0, rows, g_all[rows])
        while True:
            replay.subsets.append(current)
            g = current.g.ravel()
            ok = np.isfinite(g)
            n_ok = int(ok.sum())
            if n_ok <= seeds:
                replay.stopped = (f"subset {current.index} has {n_ok} samples that ran ok, no "
                                  f"more than the {seeds} seeds a subset needs")
                return replay
            order = np.argsort(np.where(ok, g, np.inf), kind="stable")
            ranked = g[order]
            reached = bool(ranked[seeds - 1] <= 0)
            current.threshold = 0.0 if reached else 0.5 * (ranked[seeds - 1] + ranked[seeds])
            current.probability = float(np.sum(ranked[:n_ok] <= current.threshold)) / n_ok
            with np.errstate(invalid="ignore"):
                current.hits = current.g <= current.threshold
                current.gamma = 0.0 if current.index == 0 else \
                    correlation_factor(current.hits)
            finest = current.level == self.n_levels - 1
            last = reached and finest
            previous = replay.subsets[-2] if len(replay.subsets) > 1 else None
            stuck = previous is not None and not current.changed and \
                current.threshold >= previous.threshold
            if not last and (stuck or len(replay.subsets) >= self.options.max_levels):
                replay.stopped = (
                    f"the threshold stopped falling at {current.threshold:.6g} > 0 (g ties "
                    f"there)" if stuck else
                    f"max_levels = {self.options.max_levels} subsets reached at level "
                    f"{current.level} with the threshold still at {current.threshold:.6g}")
                # as subset simulation does: the last fraction is that of failures at the
                # subset's level, so p_f is what was reached, flagged as not converged
                current.probability = float(np.sum(ranked[:n_ok] <= 0)) / n_ok
                with np.errstate(invalid="ignore"):
                    current.hits = current.g <= 0
                    current.gamma = 0.0 if current.index == 0 else \
                        correlation_factor(current.hits)
                return replay
            if last and not current.changed:
                replay.converged = True
                return replay
            # the samples of D_k: chains from its seeds, with a burn-in after a level change
            burn = burn_in if current.changed else 0
            n_chains, kept = self.chains_after(burn)
            chosen = order[:seeds]
            if reached or n_chains < seeds:
                # every sample in the event is distributed as phi given it (and D_k-1 after a
                # level change); the seeds nearest the limit are not (they lie deepest):
                # draw them at random
                inside = np.flatnonzero(ok & (g <= current.threshold))
                chosen = self.draws(current.level, current.index + 1, 0).choice(
                    inside, n_chains, replace=False)
            seed_rows = np.sort(current.points.ravel()[chosen])
            at_level = g_all.copy()
            at_level[current.points.ravel()] = g   # the seeds' margins at this level
            chain_rows = (subset_of == current.index + 1) & (stage == STAGE_CHAIN)
            chains = self.next_level(
                replay, self.as_subset_level(current), seed_rows, at_level, u_all,
                np.where(chain_rows, subset_of, -1), step_of, chain_of, length=burn + kept)
            current.acceptance, current.scale = chains.acceptance, chains.scale
            if not chains.complete:
                replay.pending = (STAGE_CHAIN, current.level, current.index + 1,
                                  replay.pending)
                return replay
            current.chain_rows, current.burn = chains.rows, burn
            points = chains.rows[:, burn:]
            kept_g = chains.g[:, burn:]
            move_up = not finest and (reached or current.on_level >=
                                      self.last_subset_on(current.level))
            nxt_level = current.level + 1 if move_up else current.level
            # the re-runs this subset's samples need: at the old level for the correction,
            # at the next level for the next subset's margins
            reruns, found = [], {}
            unique = np.unique(points)
            if current.changed:
                reruns.append((STAGE_CHECK, replay.subsets[-2].level))
            if move_up and not last:
                reruns.append((STAGE_UPDATE, nxt_level))
            for kind, level in reruns:
                rows = np.flatnonzero((stage == kind) & (subset_of == current.index + 1))
                if rows.size == 0:
                    replay.pending = (RERUN, current.index + 1,
                                      [(k, lv, unique) for k, lv in reruns])
                    return replay
                by_key = dict(zip(keys[rows].tolist(), g_all[rows].tolist()))
                found[kind] = np.vectorize(lambda row: by_key.get(int(keys[row]), math.nan),
                                           otypes=[float])(points)
            if current.changed:
                self.correct(current, replay.subsets[-2], found[STAGE_CHECK])
            if last:
                replay.converged = True
                return replay
            g_next = found[STAGE_UPDATE] if move_up else kept_g
            current = Subset(current.index + 1, nxt_level, points, g_next, changed=move_up,
                             on_level=1 if move_up else current.on_level + 1)

    def chains_after(self, burn: int) -> tuple[int, int]:
        """(chains, samples each keeps) for a subset whose chains first throw ``burn`` steps
        away. Without burn-in, subset simulation's p0 N chains of 1 / p0 states. With it,
        N // burn chains (at most p0 N) that each keep about as many states as they threw
        away (the first half of every chain discarded): the burn-in costs about N runs at
        the new level, not p0 N burn (4 N at the defaults); the longer chains' stronger
        correlation is in their gamma."""
        seeds, n = self.seeds, self.options.samples_per_level
        if burn == 0:
            return seeds, self.length
        chains = max(1, min(seeds, n // burn))
        return chains, -(-n // chains)

    @staticmethod
    def as_subset_level(subset: Subset):
        """The view of a subset ``SubsetSimulation.next_level`` takes: its index and the
        threshold its chains stay below."""
        return SubsetLevel(subset.index, subset.points, subset.g, threshold=subset.threshold)

    @staticmethod
    def correct(current: Subset, previous: Subset, g_old: np.ndarray) -> None:
        """P(D_k-1 | D_k): the fraction of the samples of D_k (after the burn-in) whose margin
        at the previous subset's level is within its threshold, with Au & Beck's c.o.v."""
        judged = np.isfinite(g_old)
        with np.errstate(invalid="ignore"):
            inside = g_old <= previous.threshold
        m = int(judged.sum())
        c = float(inside[judged].sum()) / m if m else math.nan
        current.correction, current.check_g = c, g_old
        if not (m and c > 0):
            current.correction_cov = math.inf
            return
        gamma = correlation_factor(inside) if judged.all() else 0.0
        current.correction_cov = math.sqrt((1 - c) / (m * c) * (1 + gamma))

    @staticmethod
    def subset_genealogy(subsets: list[Subset], realizations: int) -> Genealogy:
        """``influence_genealogy`` of a replay's subsets: every sample's level-0 family
        through its chain's seed (``family_roots`` over the first subset's draws and each
        subset's chains, burn-in included). A subset's samples are the previous one's
        chains' kept states, re-run at its level after a change (the rows of the points,
        not of their re-runs: a re-run is the same point); the correction's samples are its
        own chains' kept states."""
        if not subsets or not all(np.isfinite(s.probability) for s in subsets):
            return Genealogy(math.nan, 0.0)
        chained = [s for s in subsets if s.chain_rows is not None]
        lineage = [SubsetLevel(0, subsets[0].points, subsets[0].g)] + [
            SubsetLevel(i + 1, s.chain_rows, np.zeros(s.chain_rows.shape))
            for i, s in enumerate(chained)]
        roots = family_roots(lineage, realizations)
        kept = {s.index: r[:, s.burn:] for s, r in zip(chained, roots[1:])}
        fractions, corrections = [], []
        for s in subsets:
            sample_roots = roots[0] if s.index == 0 else kept[s.index - 1]
            ok = np.isfinite(s.g)
            fractions.append((sample_roots[ok], s.hits[ok]))
            if s.changed and s.check_g is not None:
                judged = np.isfinite(s.check_g)
                with np.errstate(invalid="ignore"):
                    inside = s.check_g[judged] <= subsets[s.index - 1].threshold
                corrections.append((kept[s.index][judged], inside))
        return influence_genealogy(fractions, corrections, subsets[0].points.size)

    # ------------------------------------------------------------------ statistics
    def run_costs(self, runs: xr.Dataset) -> np.ndarray:
        """Cost of one run per level, as multifidelity importance sampling takes it: stated,
        or each level's median wall time less compile time."""
        return MultifidelityImportanceSampling.run_costs(self, runs)

    def analyze(self, design, runs):
        replay = self.replay(runs)
        opts = self.options
        subsets = replay.subsets
        warnings = self.failed_run_notes(runs)
        probabilities = np.array([s.probability for s in subsets])
        corrections = np.array([s.correction for s in subsets])
        covs = np.array([s.cov for s in subsets])
        correction_covs = np.array([s.correction_cov for s in subsets])
        p_f = float(np.prod(probabilities) / np.prod(corrections))
        terms = np.concatenate([covs, correction_covs])
        cov_uncorrelated = float(math.sqrt(np.sum(terms**2)))
        cov_correlated = float(np.sum(terms))
        genealogy = self.subset_genealogy(subsets, runs.sizes[REALIZATION])
        cov = genealogy.cov
        if p_f == 0:
            cov = cov_uncorrelated = cov_correlated = math.inf
        low, high = map(float, lognormal_interval(p_f, cov, opts.confidence,
                                                  genealogy.degrees_of_freedom))
        if not replay.converged:
            warnings.append(f"multilevel subset simulation did not reach the finest level's "
                            f"failure domain ({replay.stopped}): p_f cannot be trusted")
        costs = self.run_costs(runs)
        level = np.asarray(runs[LEVEL].values)
        done = np.asarray(runs[STATUS].values != STATUS_PENDING)
        level_runs = np.array([int((done & (level == lv)).sum())
                               for lv in range(self.n_levels)])
        spent = float(np.nansum(level_runs * costs))
        with np.errstate(divide="ignore", invalid="ignore"):
            equivalent = (1.0 - p_f) / (cov**2 * p_f) if p_f > 0 and 0 < cov < math.inf \
                else math.nan
        equivalent_cost = equivalent * costs[-1]
        ratio = equivalent_cost / spent if spent > 0 else math.nan
        changes = [s.index for s in subsets if s.changed]
        one = (LIMIT_STATE,)
        data = {
            FAILURE_PROBABILITY: (one, [p_f], {
                "long_name": "probability of failure at the finest level: the subsets' "
                             "fractions over the corrections at level changes", UNITS: "1"}),
            FAILURE_INTERVAL: ((LIMIT_STATE, BOUND), [[low, high]], {
                "long_name": f"{100 * opts.confidence:g} % interval of p_f (lognormal with "
                             f"the genealogical c.o.v., Student t quantile)", UNITS: "1"}),
            FAILURE_COV: (one, [cov], {
                "long_name": "c.o.v. of p_f from the level-0 families of the fractions' and "
                             "corrections' samples (genealogical, subsets' correlation "
                             "included)", UNITS: "1"}),
            FAILURE_FAMILIES: (one, [genealogy.families], {
                "long_name": "effective number of level-0 families of the last subset's "
                             "failures (Kish); the interval's t has one fewer degrees of "
                             "freedom", UNITS: "1"}),
            FAILURE_COV_UNCORRELATED: (one, [cov_uncorrelated], {
                "long_name": "c.o.v. of p_f, the fractions and corrections uncorrelated "
                             "(Au & Beck)", UNITS: "1"}),
            FAILURE_COV_CORRELATED: (one, [cov_correlated], {
                "long_name": "c.o.v. of p_f, fully correlated", UNITS: "1"}),
            RELIABILITY_INDEX: (one, [probability.reliability_index(p_f)], {UNITS: "1"}),
            FAILURES: (one, [int(np.sum(subsets[-1].g <= 0)) if replay.converged else 0], {
                "long_name": "failures among the last subset's samples"}),
            EQUIVALENT_FINEST_RUNS: (one, [equivalent], {
                "long_name": "finest-level runs plain Monte Carlo needs for the same c.o.v., "
                             "(1 - p) / (cov^2 p)"}),
            EQUIVALENT_FINEST_COST: (one, [equivalent_cost], {
                "long_name": "their cost at the finest level's cost per run"}),
            FINEST_COST_RATIO: (one, [ratio], {
                "long_name": "equivalent finest-level Monte Carlo cost over this study's"}),
            SUBSET_FIDELITY: ((SUBSET_LEVEL,), np.array([s.level for s in subsets]), {
                "long_name": "fidelity level the subset's event is defined on"}),
            SUBSET_THRESHOLD: ((SUBSET_LEVEL,), [s.threshold for s in subsets], {
                "long_name": "threshold of g ending the subset (0 at the last)"}),
            SUBSET_PROBABILITY: ((SUBSET_LEVEL,), probabilities, {
                "long_name": "fraction of the subset's samples in its event", UNITS: "1"}),
            SUBSET_CORRECTION: ((SUBSET_LEVEL,), corrections, {
                "long_name": "at a level change P[previous event | this one] (1 elsewhere)",
                UNITS: "1"}),
            SUBSET_CORRECTION_COV: ((SUBSET_LEVEL,), correction_covs, {UNITS: "1"}),
            SUBSET_GAMMA: ((SUBSET_LEVEL,), [s.gamma for s in subsets], {UNITS: "1"}),
            SUBSET_ACCEPTANCE: ((SUBSET_LEVEL,), [s.acceptance for s in subsets], {
                "long_name": "acceptance rate of the chains that sample the subset's event",
                UNITS: "1"}),
            SUBSET_SCALE: ((SUBSET_LEVEL,), [s.scale for s in subsets], {UNITS: "1"}),
            SUBSET_COV: ((SUBSET_LEVEL,), covs, {UNITS: "1"}),
            SUBSET_SAMPLES: ((SUBSET_LEVEL,), np.array([s.samples for s in subsets])),
            FIDELITY_RUNS: ((LEVEL,), level_runs),
            FIDELITY_COST: ((LEVEL,), costs, {UNITS: "s" if opts.costs == "measured"
                                           else "stated"}),
        }
        stats = xr.Dataset(data, coords={LIMIT_STATE: [self.limit_state],
                                         BOUND: [BOUND_LOW, BOUND_HIGH],
                                         SUBSET_LEVEL: np.arange(len(subsets)),
                                         LEVEL: np.arange(self.n_levels)})
        stats = stats.assign_coords({FIDELITY_VALUE: (LEVEL, np.asarray(self.level_values,
                                                                    dtype=float))})
        self.draw_moments(stats, runs)
        for message in warnings:
            pywarnings.warn(message, AccuracyWarning, stacklevel=2)
        stats = finish_statistics(stats, design, runs, self.name, warnings)
        state = self.limit_states[self.limit_state]
        stats.attrs[LIMIT_STATE] = self.limit_state
        stats.attrs.update({
            "limit_state_event": state.describe(), "converged": int(replay.converged),
            "stop_reason": replay.stopped, CONFIDENCE: opts.confidence,
            "level_probability_p0": opts.level_probability,
            "samples_per_level": opts.samples_per_level, SUBSET_BURN_IN: opts.burn_in,
            MULTILEVEL_TOTAL_COST: spent,
            INTERVAL_METHOD: "lognormal from the genealogical c.o.v., Student t quantile "
                             "with the effective families - 1 degrees of freedom",
            FAILURE_NOTE: (f"multilevel subset simulation (Ullmann & Papaioannou), "
                           f"{len(subsets)} subsets of {opts.samples_per_level} samples on "
                           f"levels {', '.join(str(s.level) for s in subsets)}, level "
                           f"changes at subsets {changes or 'none'} with {opts.burn_in} "
                           f"burn-in steps per chain; p_f = product of the fractions over "
                           f"the corrections P[previous event | new one]; c.o.v. from the "
                           f"level-0 families of the fractions' and corrections' samples "
                           f"({genealogy.families:.3g} effective families of the failures), "
                           f"which counts the subsets' correlation through the seeds (Au & "
                           f"Beck's, terms uncorrelated: {cov_uncorrelated:.3g}; fully "
                           f"correlated: {cov_correlated:.3g}); "
                           f"{100 * opts.confidence:g} % interval lognormal with median p_f "
                           f"and a Student t quantile")})
        return stats

    @staticmethod
    def failed_run_notes(runs: xr.Dataset) -> list[str]:
        """What became of the runs that did not finish ok, by the stage they ran in."""
        stage = np.asarray(runs[STAGE].values)
        failed = ~ok_mask(runs) & np.asarray(runs[STATUS].values != STATUS_PENDING)
        what = {STAGE_DRAW: "first-subset draws did not run ok: neither failure nor safe, "
                            "left out of the subset's N (p_f is biased if solver errors "
                            "depend on the inputs)",
                STAGE_CHAIN: "chain proposals did not run ok: each was rejected (its chain "
                             "stayed), so the chains sample the events without the region "
                             "where the solver fails",
                STAGE_UPDATE: "update runs (samples re-run at the next level) did not run "
                              "ok: those samples are left out of the next subset's fraction",
                STAGE_CHECK: "check runs (samples re-run at the previous level) did not run "
                             "ok: those samples are left out of the correction"}
        return [f"{int(np.sum(failed & (stage == kind)))} {words}"
                for kind, words in what.items() if np.any(failed & (stage == kind))]

    def draw_moments(self, stats, runs) -> None:
        """Each output's mean and std over the first subset's draws (the inputs'
        distribution, at the coarsest level)."""
        first = np.flatnonzero(np.asarray(runs[STAGE].values) == STAGE_DRAW)
        ok = ok_mask(runs)[first]
        for out in output_names(runs):
            values = np.asarray(runs[out].values, dtype=float)[first][ok]
            with pywarnings.catch_warnings():
                pywarnings.simplefilter("ignore", RuntimeWarning)  # no ok run: NaN
                summary = np.stack([values.mean(axis=0), values.std(axis=0, ddof=1)])
            stats[out] = xr.DataArray(summary, dims=(STATISTIC, *runs[out].dims[1:]), attrs={
                "long_name": f"{out}: mean and std of the first subset's draws, at the "
                             f"coarsest level"})
        stats.coords[STATISTIC] = [STATISTIC_MEAN, STATISTIC_STD]
        for dim in {d for out in output_names(runs) for d in runs[out].dims[1:]}:
            if dim in runs.coords:
                stats.coords[dim] = runs[dim]

    # ------------------------------------------------------------------ report
    @classmethod
    def report(cls, view):
        """p_f with its interval and c.o.v., the subsets with their levels and corrections,
        the runs per level and what plain Monte Carlo at the finest level would cost."""
        stats = view.stats
        attrs = stats.attrs
        name = str(attrs.get(LIMIT_STATE, "?"))
        notes = []
        if FAILURE_PROBABILITY in stats:
            level = f"{100 * float(attrs.get(CONFIDENCE, 0.95)):g} %"
            low, high = stats[FAILURE_INTERVAL].values[0]
            notes.append(
                f"multilevel subset simulation, limit state '{name}': p_f at the finest level "
                f"= {number(float(stats[FAILURE_PROBABILITY].values[0]))} ({level} interval "
                f"{number(low)} .. {number(high)}, lognormal), c.o.v. "
                f"{number(float(stats[FAILURE_COV].values[0]))} (from "
                f"{number(float(stats[FAILURE_FAMILIES].values[0]))} effective level-0 "
                f"families; Au & Beck's, terms uncorrelated, "
                f"{number(float(stats[FAILURE_COV_UNCORRELATED].values[0]))}; fully "
                f"correlated {number(float(stats[FAILURE_COV_CORRELATED].values[0]))}), beta = "
                f"{number(float(stats[RELIABILITY_INDEX].values[0]))}"
                + ("" if int(attrs.get("converged", 0)) else
                   f" (NOT converged: {attrs.get('stop_reason', '')})"))
            notes.append("subset  level  threshold b      fraction         correction       "
                         "c.o.v.   gamma")
            for j in range(stats.sizes.get(SUBSET_LEVEL, 0)):
                def cell(var, width):
                    return number(float(stats[var].values[j])).ljust(width)
                notes.append(f"{j:<7d} {int(stats[SUBSET_FIDELITY].values[j]):<6d} "
                             f"{cell(SUBSET_THRESHOLD, 16)} {cell(SUBSET_PROBABILITY, 16)} "
                             f"{cell(SUBSET_CORRECTION, 16)} {cell(SUBSET_COV, 8)} "
                             f"{cell(SUBSET_GAMMA, 8)}")
            runs = [int(r) for r in stats[FIDELITY_RUNS].values]
            values = [number(float(v)) for v in stats[FIDELITY_VALUE].values]
            notes.append("runs per level (" + ", ".join(values) + "): " +
                         ", ".join(map(str, runs)) +
                         f"; burn-in {int(attrs.get(SUBSET_BURN_IN, 0))} steps per chain at "
                         f"a level change")
            notes.append(
                f"plain Monte Carlo at the finest level needs "
                f"{number(float(stats[EQUIVALENT_FINEST_RUNS].values[0]))} runs for this "
                f"c.o.v. (cost {number(float(stats[EQUIVALENT_FINEST_COST].values[0]))}); "
                f"this study cost {number(float(attrs.get(MULTILEVEL_TOTAL_COST, math.nan)))}"
                f" (their ratio {number(float(stats[FINEST_COST_RATIO].values[0]))}: above 1, "
                f"this study was the cheaper)")
        if attrs.get(FAILURE_NOTE):
            notes.append(f"p_f: {attrs[FAILURE_NOTE]}")
        total = int(attrs.get(SOLVER_RUNS, 0))
        return MethodReport(description=f"multilevel subset simulation of '{name}', "
                                        f"{total} runs", runs_are_draws=False, notes=notes,
                            figures=[FigureSpec("multilevel_subsets", subsets_figure,
                                                per_output=False)])


def subsets_figure(view, output=None):
    """The estimate after each subset on a log scale (the fractions so far over the
    corrections so far), each subset coloured by its fidelity level, the level changes
    marked with their correction, and p_f with its interval at the end."""
    stats = view.stats
    if SUBSET_PROBABILITY not in stats or not stats.sizes.get(SUBSET_LEVEL, 0):
        return None
    fractions = np.asarray(stats[SUBSET_PROBABILITY].values, dtype=float)
    corrections = np.asarray(stats[SUBSET_CORRECTION].values, dtype=float)
    fidelity = np.asarray(stats[SUBSET_FIDELITY].values, dtype=int)
    with np.errstate(divide="ignore", invalid="ignore"):
        reached = np.cumprod(fractions) / np.cumprod(corrections)
    subsets = np.arange(fractions.size)
    fig, ax = new_figure(width=6.0, height=4.2)
    colours = ["#9e9e9e", "#e08e2b", "#1f4e79", "#2ca02c", "#c0392b", "#8e44ad"]
    values = stats[FIDELITY_VALUE].values if FIDELITY_VALUE in stats.coords else []
    for lv in np.unique(fidelity):
        on = fidelity == lv
        label = f"level {lv}" + (f" ({number(float(values[lv]))})" if len(values) > lv
                                 else "")
        ax.plot(subsets[on], reached[on], marker="o", linestyle="none",
                color=colours[lv % len(colours)], label=label)
    ax.plot(subsets, reached, color="#7f7f7f", linewidth=1)
    for k in np.flatnonzero(corrections != 1.0):
        ax.annotate(f"÷ {number(float(corrections[k]))}", (subsets[k], reached[k]),
                    textcoords="offset points", xytext=(6, 6), fontsize="small")
    low, high = stats[FAILURE_INTERVAL].values[0]
    if np.isfinite(low) and np.isfinite(high):
        ax.errorbar([subsets[-1]], [reached[-1]],
                    yerr=[[reached[-1] - low], [high - reached[-1]]], color="#000000",
                    capsize=4, label=f"p_f, {100 * float(stats.attrs.get(CONFIDENCE, 0.95)):g}"
                                     f" % interval")
    ax.set_yscale("log")
    ax.set_xticks(subsets)
    ax.set_xlabel("subset")
    ax.set_ylabel("P[event of the subset] (fractions / corrections so far)")
    ax.set_title(f"{view.study}: multilevel subsets of "
                 f"'{stats.attrs.get(LIMIT_STATE, '')}'")
    ax.legend(loc="best", fontsize="small")
    return fig
