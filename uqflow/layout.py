"""The names of a result's layout, in one place: the design, the runs, the statistics, the
attributes every result carries, and what counts as an output (docs/results.md).

Every module that writes or reads a result imports its names from here; none spells them.
A result written by uqflow is an ``xr.DataTree`` with the groups ``design``, ``runs`` and
``statistics`` (``uqflow.store``).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

# ----------------------------------------------------------------------------- groups
#: the groups of a result file below its root (``uqflow.store``)
RUNS_GROUP, STATISTICS_GROUP = "runs", "statistics"

# ----------------------------------------------------------------------------- dims
REALIZATION = "realization"
PARAMETER, PARAMETER_J = "parameter", "parameter_j"
#: non-dim coordinate of ``parameter``: each input's units
PARAMETER_UNITS = "parameter_units"
#: leading dim of every output's statistics; its labels are the STATISTIC_* names below
STATISTIC = "statistic"

# ----------------------------------------------------------------------------- design
#: (realization, parameter): the parameter values of each realization
INPUTS = "inputs"
INPUT_MEAN, INPUT_STD, INPUT_CV = "input_mean", "input_std", "input_cv"
INPUT_SKEWNESS, INPUT_KURTOSIS = "input_skewness", "input_kurtosis"
#: (parameter, parameter_j): the Gaussian-copula correlation of the inputs
INPUT_CORRELATION = "input_correlation"
INPUT_SUMMARY = (INPUT_MEAN, INPUT_STD, INPUT_CV, INPUT_SKEWNESS, INPUT_KURTOSIS,
                 INPUT_CORRELATION)
#: the seed of a realization's random fields (a design with [[fields]])
REALIZATION_SEED = "realization_seed"
#: field germs and evaluated field values are named with these prefixes (``uqflow.fields``)
GERM_PREFIX, FIELD_PREFIX = "germ_", "field_"
#: boolean (realization): run with the solver's local derivatives (``uqflow.realization``)
WITH_SENSITIVITIES = "with_sensitivities"
#: what a row of a control-variate design is: ROLE_CONTROL rows build the surrogate and are
#: not draws from the inputs' distribution
ROLE, ROLE_CONTROL, ROLE_SAMPLE = "role", "control", "sample"
#: design variables of the methods that sample fidelity levels (``fidelity_sampling``)
LEVEL, GROUP, SAMPLE, SEED_KEY, ROUND = "level", "group", "sample", "seed_key", "round"
FIDELITY_DESIGN_VARIABLES = (LEVEL, GROUP, SAMPLE, SEED_KEY, ROUND)

# ----------------------------------------------------------------------------- runs
STATUS, MESSAGE = "status", "message"
STATUS_OK, STATUS_FAILED, STATUS_PENDING = "ok", "failed", "pending"
#: seconds of a realization, and the part of it numba spent compiling
WALL_TIME, COMPILE_TIME = "wall_time", "compile_time"
#: field points whose Weibull-perturbed value was clipped to the parameter's range
CLIPPED_POINTS = "clipped_points"
#: what the executor writes for every realization besides the solver's outputs
RUN_COLUMNS = (STATUS, MESSAGE, WALL_TIME, COMPILE_TIME, CLIPPED_POINTS)
#: local derivatives of sensitivity runs live on their own dim (``uqflow.realization``)
SENSITIVITY_DIM, SENSITIVITY_COORD = "sensitivity_run", "sensitivity_realization"
GRADIENT_SUFFIX, HESSIAN_SUFFIX = "__gradient", "__hessian"

# ----------------------------------------------------------------------------- statistics
STATISTIC_MEAN, STATISTIC_STD, STATISTIC_VARIANCE = "mean", "std", "variance"
#: the standard error of the mean, and the interval of the mean at the result's confidence
STATISTIC_STDERR, STATISTIC_CI_LOW, STATISTIC_CI_HIGH = "stderr", "ci_low", "ci_high"
#: attributes of the statistics group (``uqflow.methods.base.finish_statistics``)
METHOD = "method"
SOLVER_RUNS, FAILED_RUNS = "solver_runs", "failed_runs"
SOLVER_WALL_TIME, SOLVER_COMPILE_TIME = "solver_wall_time", "solver_compile_time"
#: one warning per line
WARNINGS = "warnings"
CONFIDENCE = "confidence"

# ----------------------------------------------------------------------------- limit states
#: dim of the margins, failures and failure statistics: one label per limit state and
#: system of the study's [[limit_states]] (``uqflow.limit_states``)
LIMIT_STATE = "limit_state"
#: (limit_state): P[failure] of each limit state
FAILURE_PROBABILITY = "failure_probability"
#: (limit_state, bound): the interval of P[failure]; its bounds BOUND_LOW and BOUND_HIGH
FAILURE_INTERVAL = "failure_probability_interval"
BOUND, BOUND_LOW, BOUND_HIGH = "bound", "low", "high"
#: (limit_state): the coefficient of variation of the estimate of P[failure]
FAILURE_COV = "failure_probability_cov"
#: (limit_state): the reliability index beta = -Phi^-1(P[failure])
RELIABILITY_INDEX = "reliability_index"
#: (limit_state): the count of failure events among the runs that ran ok
FAILURES = "failures"
#: attribute: how the interval of P[failure] was computed (Clopper-Pearson, Wilson, ...)
INTERVAL_METHOD = "interval_method"
#: (limit_state): the realizations that ran ok, over which P[failure] is estimated, and
#: those that did not (a solver error is neither failure nor safe: they are left out)
FAILURE_RUNS, FAILURE_LEFT_OUT = "failure_probability_runs", "failure_probability_left_out"
#: attribute: how P[failure] and its interval were estimated and what was left out, in words
FAILURE_NOTE = "failure_probability_note"

# --------------------------------------------------------- discrete outcomes (limit states)
#: output attributes (CF): a 0/1 outcome's values and their meanings ("intact broken");
#: a limit state may say ``is = true`` of it
FLAG_VALUES, FLAG_MEANINGS = "flag_values", "flag_meanings"
#: output attribute ``output_values = DISCRETE_VALUES``: the output takes discrete values (a
#: count, a cycle, a value on the loading's grid): a limit state on it has a discrete margin
OUTPUT_VALUES, DISCRETE_VALUES = "output_values", "discrete"
#: output attribute of an event's time (a cycle, an applied strain): the value it takes when
#: the event did not happen within the loading (finite: outputs hold no inf or NaN)
NOT_WITHIN_LOADING = "not_within_loading"
#: output attribute: the 0/1 outcome whose 1 leaves this output without value (a broken bar
#: has no later loops): a study storing it keeps such realizations failed
UNDEFINED_WHEN = "undefined_when"
#: attribute of a solver's run: why some of its outputs have no value (NaN), for the
#: message of a realization that stores one of them
NO_VALUE_REASON = "no_value_reason"

# monte-carlo (and the sampling methods after it): each limit state's exceedance curve
#: dim of the levels of each limit state's exceedance curve (each has its own levels: NaN
#: pads the shorter curves)
EXCEEDANCE_POINT = "exceedance_point"
#: (limit_state, exceedance_point): the levels y, increasing, in EXCEEDANCE_UNITS
EXCEEDANCE_LEVEL = "exceedance_level"
#: (limit_state, exceedance_point): P[Y >= y] or P[Y <= y] (EXCEEDANCE_COMPARISON); at the
#: threshold it is P[failure]
EXCEEDANCE_PROBABILITY = "exceedance_probability"
#: (limit_state, exceedance_point, bound): the pointwise interval of each level's probability
EXCEEDANCE_INTERVAL = "exceedance_probability_interval"
#: (limit_state): the quantity Y in words ("max of y", a system's margin), its comparison
#: (">=" or "<="), the limit state's threshold and the units of Y
EXCEEDANCE_QUANTITY, EXCEEDANCE_COMPARISON = "exceedance_quantity", "exceedance_comparison"
EXCEEDANCE_THRESHOLD, EXCEEDANCE_UNITS = "exceedance_threshold", "exceedance_units"
#: attribute: how the curve and its band were estimated, in words
EXCEEDANCE_NOTE = "exceedance_note"

# subset-simulation (uqflow.methods.subset_simulation): its rows, levels and error bounds
#: design coordinates of a row: its subset level, its Markov chain (-1 at level 0, whose
#: rows are independent draws) and its step along the chain (the proposal of that step)
SUBSET_LEVEL, CHAIN, CHAIN_STEP = "subset_level", "chain", "chain_step"
#: (subset_level): the threshold of g that ends each level (0 at the last), the conditional
#: probability of the next level's event, the chains' correlation factor gamma (Au & Beck),
#: the acceptance rate of the proposals, the scale lambda after the level, the level's
#: c.o.v. delta_j, the samples that ran ok and the runs that failed
SUBSET_THRESHOLD, SUBSET_PROBABILITY = "subset_threshold", "subset_probability"
SUBSET_GAMMA, SUBSET_ACCEPTANCE = "subset_gamma", "subset_acceptance_rate"
SUBSET_SCALE, SUBSET_COV = "subset_scale", "subset_cov"
SUBSET_SAMPLES, SUBSET_FAILED_RUNS = "subset_samples", "subset_failed_runs"
#: (limit_state): the c.o.v. of P[failure] were the levels' estimates fully correlated
#: (sum of delta_j)
FAILURE_COV_CORRELATED = "failure_probability_cov_correlated"
#: (limit_state): subset simulation's c.o.v. with the levels taken as uncorrelated (Au &
#: Beck's, sqrt of the sum of delta_j^2; FAILURE_COV is then the genealogical one), and the
#: effective number of level-0 families the last level's failures descend from (Kish)
FAILURE_COV_UNCORRELATED = "failure_probability_cov_uncorrelated"
FAILURE_FAMILIES = "failure_effective_families"

# multifidelity-importance-sampling (uqflow.methods.multifidelity_reliability)
#: (limit_state): the standard error of P[failure], and the importance weights' effective
#: sample size (Kish)
FAILURE_STDERR, EFFECTIVE_SAMPLE_SIZE = "failure_probability_stderr", "effective_sample_size"
#: (limit_state): finest-level runs plain Monte Carlo needs for the same c.o.v.,
#: (1 - p) / (cov^2 p), their cost at the finest level's cost per run, and that cost over
#: the method's (both stages)
EQUIVALENT_FINEST_RUNS, EQUIVALENT_FINEST_COST = ("equivalent_finest_runs",
                                                  "equivalent_finest_cost")
FINEST_COST_RATIO = "finest_cost_ratio"
#: (limit_state): stage 1's own P[failure] at the coarsest level (a guide, biased)
GUIDE_PROBABILITY = "guide_failure_probability"
#: (level): runs and cost of one run per fidelity level; the levels' values (coordinate)
FIDELITY_RUNS, FIDELITY_COST = "fidelity_level_runs", "fidelity_level_cost"
FIDELITY_VALUE = "fidelity_level_value"
#: (biasing_component) weights and (biasing_component, parameter) means in standard normal
#: space of the biasing density, its defensive standard normal last
BIASING_COMPONENT, BIASING_WEIGHT, BIASING_MEAN = ("biasing_component", "biasing_weight",
                                                   "biasing_mean")
#: attributes: stage 1's rounds, whether it reached the coarse failure region, the defensive
#: weight, and the cost of both stages
GUIDE_ROUNDS, GUIDE_REACHED = "guide_search_rounds", "guide_reached"
GUIDE_DEFENSIVE_WEIGHT, GUIDE_TOTAL_COST = "guide_defensive_weight", "guide_total_cost"
#: search = "form"'s refinement on the finest level (multifidelity-importance-sampling):
#: (limit_state) the first-order reliability index of the finest level's linearization where
#: the refinement ended, (g - grad g . u) / |grad g| (NaN without one); attributes: its rounds
#: and how far it moved the biasing density's centre from the coarse design point
FINEST_SEARCH_INDEX = "finest_search_reliability_index"
FINEST_SEARCH_ROUNDS, FINEST_SEARCH_SHIFT = "finest_search_rounds_run", "finest_search_shift"
#: control_variate = true (multifidelity-importance-sampling): (limit_state) the plain
#: importance-sampling estimate without the coarse control and its standard error, the
#: correlation rho of the finest and coarse weighted indicators over the pairs, the
#: coefficient alpha, the pairs N and coarse draws M the control rests on, the finest runs
#: left out of it (their coarse twin failed), and MFMC's optimal M / N at the levels' costs
PLAIN_PROBABILITY, PLAIN_STDERR = "plain_failure_probability", "plain_failure_stderr"
CONTROL_CORRELATION, CONTROL_COEFFICIENT = "control_correlation", "control_coefficient"
CONTROL_PAIRS, CONTROL_COARSE_DRAWS = "control_pairs", "control_coarse_draws"
CONTROL_LEFT_OUT, CONTROL_OPTIMAL_RATIO = "control_left_out", "control_optimal_ratio"
#: (limit_state): t of the control's coarse event g_c <= t (control_event = "matched": the
#: coarse g's linearization moved to the finest level's first-order reliability index)
CONTROL_THRESHOLD = "control_threshold"

# multilevel-subset-simulation (uqflow.methods.multilevel_subset_simulation; it writes the
# subset_* and fidelity_* names above too)
#: (subset_level): the fidelity level each subset's event is defined on, and at a level
#: change the correction P[previous event | this one] with its c.o.v. (1 and 0 elsewhere)
SUBSET_FIDELITY = "subset_fidelity_level"
SUBSET_CORRECTION, SUBSET_CORRECTION_COV = "subset_correction", "subset_correction_cov"
#: attributes: the chains' burn-in steps at a level change, and the cost of all the runs
SUBSET_BURN_IN, MULTILEVEL_TOTAL_COST = "subset_burn_in", "multilevel_total_cost"

# importance-sampling and cross-entropy (uqflow.methods.importance_sampling; they write
# FAILURE_STDERR and EFFECTIVE_SAMPLE_SIZE above too)
#: design coordinate (realization): log phi(u) - log q(u) of the density a row was drawn from
LOG_LIKELIHOOD_RATIO = "log_likelihood_ratio"
#: (cross_entropy_round): each round's threshold of g and its count of elite draws
CE_ROUND, CE_THRESHOLD, CE_ELITES = ("cross_entropy_round", "cross_entropy_threshold",
                                     "cross_entropy_elites")
#: attributes: solver runs that built the biasing density and that sampled it, the density in
#: words, and whether the cross-entropy threshold reached 0
DENSITY_RUNS, SAMPLING_RUNS = "density_runs", "sampling_runs"
BIASING_DENSITY, THRESHOLD_REACHED = "biasing_density", "threshold_reached"
# cross-entropy's improved rule and families (uqflow.methods.importance_sampling)
#: (cross_entropy_round): the smoothing parameter s_j fitted after each round (NaN for the
#: round that met the stop) and the round's stopping c.o.v. of 1[g <= 0] / Phi(-g/s)
CE_SMOOTHING, CE_STOP_COV = "cross_entropy_smoothing", "cross_entropy_stop_cov"
#: attributes: the update rule ("improved", "quantile") and the family fitted ("gaussian",
#: "vmfn"); for vmfn the final density's concentration, Nakagami shape m and spread Omega
CE_RULE, CE_FAMILY = "cross_entropy_rule", "cross_entropy_family"
VMF_KAPPA, NAKAGAMI_M, NAKAGAMI_OMEGA = "vmf_kappa", "nakagami_m", "nakagami_omega"
#: (parameter): the final vMFN density's mean direction in standard normal space
VMF_DIRECTION = "vmf_mean_direction"

# ----------------------------------------------------------------------------- root attributes
STUDY_NAME, SOLVER = "study_name", "solver"
COMPLETE, STOPPED_EARLY, ELAPSED_TIME = "complete", "stopped_early", "elapsed_time"
#: the study file's path and text (or, for a text too large to store, why it is not there)
STUDY_FILE, STUDY_TEXT, STUDY_TEXT_OMITTED = "study_file", "study", "study_text_omitted"
#: provenance hashes: the study as run (text, files it reads, overrides) and its text alone
STUDY_HASH, STUDY_TEXT_HASH = "study_sha256", "study_text_sha256"
#: JSON {key: [path, sha256]} of the other files the study reads (a scene file)
STUDY_READ_FILES = "study_read_files"
SOLVER_DESCRIPTION, METHOD_OPTIONS, SEED = "solver_description", "method_options", "seed"
PLANNED_REALIZATIONS, WORKERS = "planned_realizations", "workers"
#: compiling the solver's code before the first run (uqflow/warm_up.py): wall seconds, numba's
#: compile seconds summed over the processes, and how many processes shared the work
WARM_UP_TIME, WARM_UP_COMPILE_TIME = "warm_up_time", "warm_up_compile_time"
WARM_UP_PROCESSES = "warm_up_processes"
CREATED, FINISHED, RESUMED = "created", "finished", "resumed"
#: SHA-256 of the stored runs, verified before a resume trusts them (``uqflow.store``)
RUNS_HASH = "runs_sha256"
#: CF attributes of the file: a title, and the conventions it follows
TITLE, CONVENTIONS = "title", "Conventions"
#: ``version_<package>``: the versions of uqflow and of the libraries a result was made with
VERSION_PREFIX = "version_"
#: command-line overrides of study keys (``uqflow run --set``), as TOML lines
STUDY_OVERRIDES = "study_overrides"

# ----------------------------------------------------------------------------- output attributes
#: attributes of an output variable (CF conventions): its units and a label a reader
#: understands ("deviatoric stress s_xx"); the report draws and tabulates with them
UNITS, LONG_NAME = "units", "long_name"
#: ``output_kind = DIAGNOSTIC_KIND`` marks a timing or counter of the run, not an uncertain
#: quantity: stored with the runs, given no statistics, figure or allocation
OUTPUT_KIND, DIAGNOSTIC_KIND, QUANTITY_KIND = "output_kind", "diagnostic", "quantity"


def gradient_variable(output: str) -> str:
    """Name of the local gradient of ``output`` (in a solver's dataset and in the runs)."""
    return output + GRADIENT_SUFFIX


def hessian_variable(output: str) -> str:
    """Name of the local Hessian of ``output`` (in a solver's dataset and in the runs)."""
    return output + HESSIAN_SUFFIX


def is_sensitivity_variable(name) -> bool:
    return str(name).endswith((GRADIENT_SUFFIX, HESSIAN_SUFFIX))


def is_diagnostic(variable: xr.DataArray) -> bool:
    """Whether an output is a diagnostic of the run (a timing, a counter), not an uncertain
    quantity: its attribute ``output_kind`` is ``DIAGNOSTIC_KIND``."""
    return str(variable.attrs.get(OUTPUT_KIND, "")) == DIAGNOSTIC_KIND


#: variables with a realization dim that are the framework's, never a solver's output
_NOT_OUTPUTS = frozenset({INPUTS, *RUN_COLUMNS, REALIZATION_SEED, WITH_SENSITIVITIES, ROLE,
                          *FIDELITY_DESIGN_VARIABLES})


def output_names(runs: xr.Dataset) -> list[str]:
    """The uncertain solver outputs stored in ``runs``: every variable with a ``realization``
    dim but the framework's own, the field germs and values, and the solver's diagnostics."""
    return [str(v) for v in runs.data_vars if v not in _NOT_OUTPUTS
            and REALIZATION in runs[v].dims
            and not str(v).startswith((GERM_PREFIX, FIELD_PREFIX)) and not is_diagnostic(runs[v])]


def ok_mask(runs: xr.Dataset) -> np.ndarray:
    """The realizations that ran ok."""
    return np.asarray(runs[STATUS].values == STATUS_OK)


def sample_mask(runs: xr.Dataset) -> np.ndarray:
    """The runs that are draws from the inputs' distribution: ok, and not a control variate's
    control runs (``role = "control"``: stencil points at and around the input means)."""
    samples = ok_mask(runs)
    if ROLE in runs.variables:
        samples &= np.asarray(runs[ROLE].values) != ROLE_CONTROL
    return samples
