"""Control variates for Monte Carlo: a Taylor surrogate whose mean is known.

A few control realizations at the start of the design give the second-order Taylor
polynomial of every output around the input means,

    g(x) = f(mu) + J.(x - mu) + 1/2 (x - mu)' H (x - mu),

either from the solver's local derivatives (``control = "taylor-local"``: one realization run
with ``with_sensitivities``) or from the central differences of ``taylor``'s stencil
(``control = "taylor"``: 2n + 1 realizations, gradient and diagonal Hessian). g costs nothing
to evaluate at the Monte Carlo samples, and its mean and variance under the inputs are known in
closed form, so the sample mean of f can be corrected by how far the sample mean of g missed
its own. The estimators, their bias and their errors are derived in docs/control_variates.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from uqflow.errors import StudyError
from uqflow.layout import (INPUTS, INPUT_CORRELATION, INPUT_KURTOSIS, INPUT_SKEWNESS, INPUT_STD,
                           MESSAGE, PARAMETER, REALIZATION, ROLE, STATUS, STATUS_FAILED, STATUS_OK,
                           STATUS_PENDING, UNITS)
from uqflow.methods.base import make_design, ok_mask, output_names
from uqflow.methods.taylor import Taylor, _second_order_variance, _Stencil
from uqflow.methods.taylor_local import ALTERNATIVE, TaylorLocal
from uqflow.realization import SENSITIVITY_FLAG, sensitivity_arrays

CONTROLS = ("none", "taylor-local", "taylor")
#: Interleaved folds of i.i.d. samples (sample j in fold j mod 8): the slope beta used on a
#: fold comes from the other seven, so it is independent of that fold and its correction
#: has mean 0 exactly. Randomized QMC uses its replicates as the folds.
CROSS_FIT_FOLDS = 8
CONTROL_ALTERNATIVE = "use control = \"taylor\" (2n+1 finite-difference runs around the means)"


class ControlFailed(Exception):
    """The control realizations cannot give a surrogate (a failed run, a missing derivative)."""


def check_space(control: str, step: float, space) -> None:
    """Refuse at load time what the control cannot treat: a stencil step lost to rounding
    (``taylor``), and inputs for which the surrogate's mean and variance are not closed-form
    (they are for normal inputs with any correlation and for independent ones)."""
    if control == "taylor":
        control_design(control, step, space)
    active = np.flatnonzero(space.stds > 0)
    normal = all(space.inputs[k].kind == "normal" for k in active)
    rho = space.correlation
    correlated = any(rho[k, j] != 0 for k in active for j in active if k < j)
    if correlated and not normal:
        raise StudyError("a control needs the mean and variance of its quadratic surrogate, "
                         "closed-form for normal inputs (any correlation) or independent "
                         "ones, not for correlated non-normal inputs (their Pearson covariance "
                         "is not the copula's); drop the correlation or use control = "
                         "\"none\"", key="method.control")


def check_solver(control, solver, outputs, parameter_names) -> None:
    """``control = "taylor-local"`` needs the solver's local sensitivities (the test of
    ``taylor-local``), with ``control = "taylor"`` named as the alternative."""
    if control != "taylor-local":
        return
    try:
        TaylorLocal().check_solver(solver, outputs, parameter_names)
    except StudyError as err:
        key = "method.control" if err.key == "method.kind" else err.key
        raise StudyError(err.reason.replace(ALTERNATIVE, CONTROL_ALTERNATIVE),
                         key=key) from None


def control_design(control: str, step: float, space) -> xr.Dataset:
    """The control realizations alone, as a design (coordinates ``stencil`` and ``offset``)."""
    if control == "taylor":
        try:
            return Taylor(step=step, step_check=False, mixed_derivatives=False).plan(
                space, None, np.random.SeedSequence(0))
        except StudyError as err:
            raise StudyError(err.reason.replace("a larger step", "a larger control_step"),
                             key="method.control_step") from None
    design = make_design(space, space.means[None, :])
    return design.assign_coords(offset=((REALIZATION, PARAMETER),
                                        np.zeros((1, len(space)))),
                                stencil=(REALIZATION, np.array(["mean"], dtype=object)))


def with_control(control: str, step: float, space, samples: xr.Dataset) -> xr.Dataset:
    """``samples`` (a plain Monte Carlo design) with the control realizations put first.

    The sample rows keep their values and order, so a study samples the same points with and
    without a control; ``role`` says which row is which, ``attrs["control_runs"]`` how many
    come first.
    """
    head = control_design(control, step, space)
    m, n = head.sizes[REALIZATION], samples.sizes[REALIZATION]
    values = np.vstack([head[INPUTS].values, samples[INPUTS].values])
    variables = {}
    if "step" in head:
        variables["step"] = head["step"]
    if control == "taylor-local":
        flags = np.zeros(m + n, dtype=bool)
        flags[:m] = True
        variables[SENSITIVITY_FLAG] = (REALIZATION, flags)
    design = make_design(space, values, **variables)
    offset = np.vstack([head["offset"].values, np.full((n, len(space)), np.nan)])
    stencil = np.concatenate([head["stencil"].values, np.full(n, "", dtype=object)])
    role = np.array(["control"] * m + ["sample"] * n, dtype=object)
    # Coordinates, not data variables: everything in runs with a realization dim is taken
    # for a solver output (base.output_names).
    design = design.assign_coords(
        offset=((REALIZATION, PARAMETER), offset,
                {"long_name": "control stencil offset from the input means (NaN: a sample)"}),
        stencil=(REALIZATION, stencil, {"long_name": "control stencil point ('': a sample)"}),
        **{ROLE: (REALIZATION, role, {"long_name": "control (builds the surrogate) or "
                                                     "sample (Monte Carlo)"})})
    design.attrs.update(samples.attrs)
    active = np.flatnonzero(space.stds > 0)
    design.attrs.update(control=control, control_runs=m, normal_inputs=int(
        all(space.inputs[k].kind == "normal" for k in active)))
    if control == "taylor":
        design.attrs["control_step"] = step
    return design


def control_count(design) -> int:
    """How many control realizations open the design (0 without a control)."""
    return int(design.attrs.get("control_runs", 0))


@dataclass
class Surrogate:
    """The quadratic surrogate of one output, flattened to points: f0 (P), J (n, P), H (n, n, P);
    its exact mean and variance under the inputs (P)."""

    centre: np.ndarray
    f0: np.ndarray
    gradient: np.ndarray
    hessian: np.ndarray
    mean: np.ndarray
    variance: np.ndarray

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """g at the rows of ``x`` (N, n): (N, P). The quadratic term is one matrix product
        of the pairwise products d_k d_j with H, which stays fast for long output series."""
        d = x - self.centre
        n = d.shape[1]
        pairs = (d[:, :, None] * d[:, None, :]).reshape(d.shape[0], n * n)
        return (self.f0 + d @ self.gradient
                + 0.5 * pairs @ self.hessian.reshape(n * n, -1))


def build_surrogates(design, runs) -> dict[str, Surrogate]:
    """Every output's surrogate from the control realizations; ``ControlFailed`` if one of
    them failed or left a derivative that is not a number."""
    control = design.attrs["control"]
    m = control_count(design)
    status = runs[STATUS].values[:m]
    bad = np.flatnonzero(status != STATUS_OK)
    if bad.size:
        r = int(bad[0])
        why = "did not run" if status[r] == STATUS_PENDING else \
            (str(runs[MESSAGE].values[r]) or "no message")
        raise ControlFailed(f"control realization {r} (stencil point "
                            f"{design['stencil'].values[r]}) failed: {why}")
    s = design[INPUT_STD].values
    covariance = np.outer(s, s) * design[INPUT_CORRELATION].values
    active = s > 0
    normal = bool(design.attrs.get("normal_inputs", 0))
    mu = design[INPUTS].values[0]  # the centre row: the input means
    surrogates = {}
    for out in output_names(runs):
        f0 = np.asarray(runs[out].values[0], dtype=float).reshape(-1)
        if control == "taylor-local":
            index, gradients, hessians = sensitivity_arrays(runs, out)
            run = int(np.flatnonzero(index == 0)[0])
            g = np.moveaxis(gradients[run], -1, 0)
            hess = np.moveaxis(hessians[run], (-2, -1), (0, 1))
        else:
            g, hess = _stencil_derivatives(design, runs, out, m)
        n = s.size
        g = np.where(active[:, None], g.reshape(n, -1), 0.0)
        hess = np.where(np.outer(active, active)[:, :, None], hess.reshape(n, n, -1), 0.0)
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(hess))
                and np.all(np.isfinite(f0))):
            raise ControlFailed(f"the surrogate of '{out}' has derivatives that are not "
                                f"numbers")
        mean = f0 + 0.5 * np.einsum("kjp,kj->p", hess, covariance)
        surrogates[out] = Surrogate(mu, f0, g, hess, mean,
                                    _surrogate_variance(g, hess, covariance, design, normal))
    return surrogates


def _stencil_derivatives(design, runs, out, m):
    """Central-difference gradient and diagonal Hessian from ``taylor``'s stencil."""
    head = design.isel(realization=slice(0, m))
    stencil = _Stencil(head)
    x = head[INPUTS].values
    x = np.vstack([x - x[stencil.centre], np.full((1, x.shape[1]), np.nan)])
    y = np.asarray(runs[out].values[:m], dtype=float).reshape(m, -1)
    y = np.concatenate([y, np.full((1, y.shape[1]), np.nan)])  # row -1: a missing point
    g, hess, computed = stencil.derivatives(y, x, 1.0)
    # The surrogate has the diagonal curvature only: no mixed points were run.
    return g, np.where(computed[:, :, None], hess, 0.0)


def _surrogate_variance(g, hess, covariance, design, normal):
    """Var g under the inputs: exact for normal inputs with any correlation (Isserlis:
    J C J' + tr((H C)^2) / 2) and for independent inputs of any distribution (their third
    and fourth moments)."""
    if normal:
        hc = np.einsum("kip,ij->kjp", hess, covariance)
        return (np.einsum("kp,kj,jp->p", g, covariance, g)
                + 0.5 * np.einsum("kjp,jkp->p", hc, hc))
    s = design[INPUT_STD].values
    mu3 = np.where(s > 0, design[INPUT_SKEWNESS].values * s**3, 0.0)
    mu4 = np.where(s > 0, np.nan_to_num(design[INPUT_KURTOSIS].values) * s**4, 0.0)
    computed = np.ones((s.size, s.size), dtype=bool)
    return _second_order_variance(g, hess, computed, s, mu3, mu4, ("point",))


@dataclass
class Estimates:
    """Control-variate estimates of one output, flattened to points (P each)."""

    mean: np.ndarray
    stderr: np.ndarray
    dof: int
    variance: np.ndarray
    variance_stderr: np.ndarray | None  # None: the design gives no estimate of it
    correlation: np.ndarray
    beta: np.ndarray
    fold_means: np.ndarray  # (folds, P): each fold's (replicate's) estimate of the mean


def estimate(y, g, fold, folds, surrogate_mean, surrogate_variance, rqmc: bool) -> Estimates:
    """Control-variate mean and variance from the successful samples ``y`` and their surrogate
    values ``g`` (N, P); ``fold`` (N,) in 0 .. folds - 1 (the replicates of randomized QMC).

    Mean: per fold, ybar_f - beta_(-f) (gbar_f - E g), beta_(-f) the regression slope of y on
    g over the other folds; i.i.d.: their average weighted by fold size, stderr
    sqrt((1 - rho^2) s_f^2 / N) with N - 2 degrees of freedom; RQMC: their plain average,
    stderr their spread / sqrt(R) with R - 1. Variance: s_f^2 - beta_v (s_g^2 - Var g), beta_v
    the slope between the squared centred values; its stderr the i.i.d. delta-method one or
    the spread of the per-replicate estimates.
    """
    n = y.shape[0]
    p = y.shape[1]
    nan = np.full(p, np.nan)
    if n < 2:
        return Estimates(nan, nan, 0, nan, None, nan, nan, np.full((folds, p), np.nan))
    varies = ~(np.all(g == g[0], axis=0) | np.all(y == y[0], axis=0))
    # Centring is for the digits only: every slope below is unchanged by a shift.
    y_mean, g_mean = y.mean(axis=0), g.mean(axis=0)
    yc, gc = y - y_mean, g - g_mean
    s_ff = np.sum(yc**2, axis=0) / (n - 1)
    s_gg = np.sum(gc**2, axis=0) / (n - 1)
    s_fg = np.sum(yc * gc, axis=0) / (n - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(varies, np.clip(s_fg / np.sqrt(s_ff * s_gg), -1.0, 1.0), 0.0)
    # The sums behind rho carry a relative rounding of up to n eps each, so a 1 - rho^2 below
    # 2 n eps is rounding: the surrogate reproduces the output, and rho is +-1.
    rho = np.where(1 - rho**2 <= 2 * n * np.finfo(float).eps, np.sign(rho), rho)

    member = fold[:, None] == np.arange(folds)[None, :]
    size = member.sum(axis=0).astype(float)
    sums = {k: member.T.astype(float) @ v for k, v in
            (("y", yc), ("g", gc), ("yg", yc * gc), ("gg", gc**2), ("yy", yc**2))}
    rest = n - size[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        rest_y, rest_g = sums["y"].sum(0) - sums["y"], sums["g"].sum(0) - sums["g"]
        cov = (sums["yg"].sum(0) - sums["yg"] - rest_y * rest_g / rest) / (rest - 1)
        var = (sums["gg"].sum(0) - sums["gg"] - rest_g**2 / rest) / (rest - 1)
        beta_fold = np.where(varies & (rest >= 2) & (var > 0), cov / var, 0.0)
        fold_y = y_mean + sums["y"] / size[:, None]
        fold_g = g_mean + sums["g"] / size[:, None]
    fold_means = fold_y - beta_fold * (fold_g - surrogate_mean)
    present = size > 0
    fold_means[~present] = np.nan
    weights = size[present] / n
    with np.errstate(divide="ignore", invalid="ignore"):
        beta = np.where(varies & (s_gg > 0), s_fg / s_gg, 0.0)
    if rqmc:
        count = int(present.sum())
        mean = fold_means[present].mean(axis=0)
        spread = fold_means[present].std(axis=0, ddof=1) if count > 1 else nan
        stderr, dof = spread / np.sqrt(count), count - 1
    else:
        mean = np.einsum("f,fp->p", weights, fold_means[present])
        stderr, dof = np.sqrt(np.maximum(1 - rho**2, 0.0) * s_ff / n), n - 2

    a, b = yc**2, gc**2
    a_c, b_c = a - a.mean(axis=0), b - b.mean(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        b_var = np.sum(b_c**2, axis=0)
        beta_v = np.where(varies & (b_var > 0), np.sum(a_c * b_c, axis=0) / b_var, 0.0)
    variance = s_ff - beta_v * (s_gg - surrogate_variance)
    if rqmc:
        with np.errstate(divide="ignore", invalid="ignore"):
            within_f = (sums["yy"] - sums["y"]**2 / size[:, None]) / (size[:, None] - 1)
            within_g = (sums["gg"] - sums["g"]**2 / size[:, None]) / (size[:, None] - 1)
        fold_vars = (within_f - beta_v * (within_g - surrogate_variance))[size > 1]
        variance_stderr = fold_vars.std(axis=0, ddof=1) / np.sqrt(fold_vars.shape[0]) \
            if fold_vars.shape[0] > 1 else nan
    else:
        residual = a - beta_v * b
        variance_stderr = residual.std(axis=0, ddof=1) / np.sqrt(n)
    # An output equal at every sample, or a surrogate that does not move: no correction.
    const_y = np.all(y == y[0], axis=0)
    mean = np.where(const_y, y[0], mean)
    stderr = np.where(const_y, 0.0, stderr)
    variance = np.where(const_y, 0.0, variance)
    if np.any(np.isfinite(variance_stderr)):
        variance_stderr = np.where(const_y, 0.0, variance_stderr)
    else:  # randomized QMC with replicates of one sample: no within-replicate variance
        variance_stderr = None
    return Estimates(mean, stderr, dof, variance, variance_stderr, rho, beta, fold_means)


def sample_part(design, runs):
    """The Monte Carlo samples of a design and its runs, without the control rows."""
    m = control_count(design)
    return (design.isel(realization=slice(m, None)), runs.isel(realization=slice(m, None)))


def sample_estimates(surrogate: Surrogate, design, runs, out, folds: int, rqmc: bool,
                     count: int | None = None, g: np.ndarray | None = None) -> Estimates:
    """``estimate`` for ``out`` over the first ``count`` samples (all by default); failed
    samples are dropped from f and g alike, so every pair stays matched. ``g``: the surrogate
    at every sample, if already evaluated."""
    m = control_count(design)
    if g is None:
        g = surrogate(design[INPUTS].values[m:])
    values = np.asarray(runs[out].values[m:], dtype=float)
    ok = ok_mask(runs)[m:]
    if count is not None:
        g, values, ok = g[:count], values[:count], ok[:count]
    y = values[ok].reshape(int(ok.sum()), -1)
    g = g[ok]
    fold = np.flatnonzero(ok) % folds
    return estimate(y, g, fold, folds, surrogate.mean, surrogate.variance, rqmc)


def control_variables(out, runs, dims, est: Estimates, n, shape, plain, surrogate):
    """The statistics' variables that say what the control bought, for output ``out``."""
    units = runs[out].attrs.get(UNITS, "")
    rho2 = est.correlation**2
    with np.errstate(divide="ignore"):
        reduction = 1.0 / (1.0 - rho2)

    def field(values, long_name, unit="1"):
        return (dims, np.reshape(values, shape), {"long_name": long_name, UNITS: unit})

    variables = {
        f"{out}_correlation": field(
            est.correlation, f"correlation rho of {out} with its control surrogate over the "
                             f"successful samples"),
        f"{out}_variance_reduction": field(
            reduction, "1/(1 - rho^2): the variance of the plain mean over that of the "
                       "control-variate mean (i.i.d. theory)"),
        f"{out}_equivalent_samples": field(
            n * reduction, "n/(1 - rho^2): plain Monte Carlo samples with the same error"),
        f"{out}_control_slope": field(
            est.beta, f"pooled regression slope of {out} on its surrogate (the folds use "
                      f"leave-one-fold-out slopes)"),
        f"{out}_plain": (("plain_statistic", *dims), np.stack(plain), {
            "long_name": f"plain Monte Carlo mean, variance and stderr of the mean of {out} "
                         f"over the same samples", UNITS: units}),
        f"{out}_surrogate": (("surrogate_statistic", *dims),
                             np.stack([surrogate.mean, surrogate.variance]).reshape(
                                 (2, *shape)), {
            "long_name": f"exact mean and variance of the surrogate of {out} under the inputs",
            UNITS: units}),
    }
    # Without a standard error of the variance (randomized QMC with replicates of one
    # sample) none is written, rather than a variable of NaN (or of zeros where y is constant).
    if est.variance_stderr is not None:
        variables[f"{out}_variance_stderr"] = field(
            est.variance_stderr, f"standard error of the control-variate variance of {out}",
            f"({units})^2" if units else "1")
    return variables


def control_trace(surrogate, design, runs, out, dims, replicates, points):
    """Running control-variate mean, std and stderr after the first n samples (log-spaced;
    randomized QMC: whole replicate prefixes R 2^k)."""
    m = control_count(design)
    total = runs.sizes[REALIZATION] - m
    if replicates is None:
        counts = np.unique(np.round(np.geomspace(2, max(total, 2), points)).astype(int))
    else:
        counts = replicates * 2 ** np.arange(int(np.log2(max(total // replicates, 1))) + 1)
        counts = np.unique(np.append(counts[counts <= total], total // replicates * replicates))
    counts = counts[(counts > 0) & (counts <= total)]
    if counts.size == 0:
        counts = np.array([max(total, 1)])
    g = surrogate(design[INPUTS].values[m:])
    shape = runs[out].shape[1:]
    rows = []
    for c in counts:
        est = sample_estimates(surrogate, design, runs, out, replicates or CROSS_FIT_FOLDS,
                               replicates is not None, int(c), g)
        rows.append(np.stack([est.mean, np.sqrt(np.maximum(est.variance, 0.0)),
                              est.stderr]).reshape((3, *shape)))
    return (("trace_samples", "trace_statistic", *dims), np.stack(rows),
            {"long_name": "running control-variate estimates against sample count"}), counts


def control_attrs(design, samples, used: bool) -> dict:
    """Attributes saying which control ran, what it cost and how failures were treated."""
    failed = int(np.sum(samples[STATUS].values == STATUS_FAILED))
    return {
        "control": design.attrs["control"],
        "control_runs": control_count(design),
        "control_used": int(used),
        "control_failures": (
            "the control realizations failed: no surrogate, plain Monte Carlo" if not used
            else f"{failed} failed sample(s) dropped from both the outputs and the surrogate "
                 f"values (the pairs stay matched)"),
    }


def report_lines(stats, outputs: list[str], focus_of, where_of) -> list[str]:
    """What the control variate bought, per output at its row's point, for the report's notes
    (docs/control_variates.md); none for a result without a control. ``focus_of(out)`` is an
    output's row point, ``where_of(focus)`` its words."""
    if not stats.attrs.get("control"):
        return []
    if not int(stats.attrs.get("control_used", 0)):
        return [f"control variate {stats.attrs['control']}: not used (its control runs "
                f"failed), plain Monte Carlo"]
    lines = [f"control variate {stats.attrs['control']} ({stats.attrs['control_runs']} "
             f"control run(s)): correlation rho with the surrogate, variance reduction "
             f"1/(1 - rho^2), equivalent plain samples n/(1 - rho^2)"]
    for out in outputs:
        if f"{out}_correlation" not in stats:
            continue
        focus = focus_of(out)
        rho, gain, count = (float(stats[f"{out}_{v}"].isel(focus)) for v in
                            ("correlation", "variance_reduction", "equivalent_samples"))
        where = f" at {where_of(focus)}" if focus else ""
        if np.isfinite(gain):
            lines.append(f"  {out}{where}: rho {rho:.6g}, reduction {gain:.3g}x, "
                         f"equivalent to {count:.3g} plain samples")
        else:
            lines.append(f"  {out}{where}: rho 1, the surrogate reproduces it to rounding "
                         f"(no error left to reduce)")
    return lines


def described(stats) -> str:
    """The control variate in words, for a legend ('' without one)."""
    control = stats.attrs.get("control")
    if not control:
        return ""
    if not int(stats.attrs.get("control_used", 0)):
        return f"its {control} control variate unused (the control runs failed)"
    runs = int(stats.attrs.get("control_runs", 0))
    if control == "taylor-local":
        return f"{'one' if runs == 1 else runs}-run Taylor as control variate"
    return f"Taylor from {runs} finite-difference runs as control variate"
