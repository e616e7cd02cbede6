"""Taylor (perturbation) method: moments of the outputs from derivatives at the input means.

Seed 000, section 4.1: the mean from the second-order expansion (eq. 22), the variance from
the first-order one (eq. 24), both with the inputs' correlations; optionally the full variance
of the quadratic expansion, which needs the inputs' third and fourth moments. The derivatives
are central finite differences on a stencil around the means, with steps a fraction of each
input's std; a repeat at half the step says how much each derivative depends on the step.
See docs/taylor.md.
"""

from __future__ import annotations

import warnings as pywarnings
from typing import Literal

import numpy as np
import xarray as xr
from pydantic import Field, field_validator, model_validator

from uqflow.errors import AccuracyWarning, StudyError
from uqflow.layout import (INPUTS, INPUT_CORRELATION, INPUT_CV, INPUT_KURTOSIS, INPUT_SKEWNESS,
                           INPUT_STD, MESSAGE, PARAMETER, PARAMETER_J, REALIZATION, SOLVER_RUNS,
                           STATISTIC, STATUS, STATUS_OK, STATUS_PENDING, UNITS)
from uqflow.methods.base import (MethodOptions, PropagationMethod, finish_statistics,
                                 make_design, ok_mask, output_names, register_method)
from uqflow.report import Column, MethodReport, Sensitivity

LABELS = ["mean", "variance", "std", "nominal"]
# Relative rounding granted to every solver value when telling a derivative from noise:
# a few dozen ulps, what a chain of floating-point operations typically accumulates.
NOISE = 64 * np.finfo(float).eps
# Largest step, as a fraction of the std: the central differences err by (h/sigma)^2 relative
# to the terms the expansion keeps (docs/taylor.md, "Stencil and cost"), so at h = sigma the
# "derivative" is as much the function's spread over the distribution as its slope at the
# mean, and a stencil beyond it leaves the inputs' bulk (and a positive input's support).
MAX_STEP = 1.0
# Largest step_tolerance: the step check's change |d(h) - d(h/2)| / max(|d(h)|, |d(h/2)|) is
# at most 2 (triangle inequality), so a tolerance of 2 or more could never report anything.
MAX_STEP_TOLERANCE = 2.0


class TaylorOptions(MethodOptions):
    order: Literal[1, 2] = Field(2, description="1: mean = f(mu); 2: mean with curvature "
                                                "(seed 000 eq. 22)")
    step: float = Field(0.1, gt=0, description="finite-difference step as a fraction of "
                                                "each input's std")
    step_check: bool = Field(True, description="repeat the stencil at half the step and "
                                               "report how much each derivative changes")
    step_tolerance: float = Field(0.05, gt=0, description="relative change above which a "
                                                          "derivative is not step-stable")
    variance: Literal["first-order", "second-order"] = Field(
        "first-order", description="first-order: seed 000 eq. 24; second-order: the full "
                                   "variance of the quadratic expansion (independent inputs)")
    mixed_derivatives: Literal["auto"] | bool = Field(
        "auto", description="auto: only where they enter an estimate (correlated pairs for "
                            "the order-2 mean, every pair for the second-order variance)")
    cv_warning: float = Field(0.15, ge=0, description="warn about inputs with a larger C.V. "
                                                      "(seed 000 sec. 4.1)")

    @field_validator("step")
    @classmethod
    def _step_within_a_std(cls, step):
        if step > MAX_STEP:
            raise ValueError(f"must be <= {MAX_STEP:g} (a fraction of each input's std: a "
                             f"larger stencil leaves the inputs' bulk and the differences no "
                             f"longer measure a derivative at the mean), got {step!r}")
        return step

    @field_validator("step_tolerance")
    @classmethod
    def _tolerance_can_fire(cls, tolerance):
        if tolerance >= MAX_STEP_TOLERANCE:
            raise ValueError(f"must be < {MAX_STEP_TOLERANCE:g} (the step check's relative "
                             f"change is at most 2, so it would never report; set "
                             f"step_check = false to skip the check), got {tolerance!r}")
        return tolerance

    @model_validator(mode="after")
    def _mixed_need_curvature(self):
        if self.mixed_derivatives is True and self.order == 1 and \
                self.variance == "first-order":
            raise ValueError("mixed derivatives enter only the order-2 mean and the "
                             "second-order variance; set order = 2 or drop mixed_derivatives")
        return self


def _label(value) -> str:
    """A coordinate value for a message: numbers compactly, labels (probe names) as they are."""
    return f"{value:g}" if isinstance(value, (int, float, np.number)) else str(value)


def _independence_error() -> StudyError:
    return StudyError("the second-order variance needs the joint third and fourth moments of "
                      "correlated inputs, which a Gaussian copula does not give in closed "
                      "form; use variance = \"first-order\" or monte-carlo",
                      key="method.variance")


@register_method("taylor")
class Taylor(PropagationMethod):
    """Taylor expansion at the input means: f(mu), gradient and Hessian by central differences."""

    Options = TaylorOptions

    # ------------------------------------------------------------------ plan
    def check(self, space, fields):
        super().check(space, fields)
        opts = self.options
        h = opts.step * space.stds
        active = np.flatnonzero(h > 0)
        rho = space.correlation
        if opts.variance == "second-order" and \
                any(rho[k, j] != 0 for k in active for j in active if k < j):
            raise _independence_error()
        mu, smallest = space.means, (0.5 if opts.step_check else 1.0) * h
        lost = [space.names[k] for k in active
                if mu[k] + smallest[k] == mu[k] or mu[k] - smallest[k] == mu[k]]
        if lost:
            raise StudyError(f"the std of '{lost[0]}' is too small next to its mean for a "
                             f"finite difference (mean + step rounds to the mean); give it "
                             f"std 0 or a larger step", key="method.step")

    def plan(self, space, fields, seed):
        self.check(space, fields)
        opts = self.options
        names, mu = space.names, space.means
        h = opts.step * space.stds
        active = np.flatnonzero(h > 0)
        rho = space.correlation

        offsets, labels = [np.zeros(len(space))], ["mean"]

        def axis(k, frac, tag):
            for sign, s in ((1, "+"), (-1, "-")):
                row = np.zeros(len(space))
                row[k] = sign * frac * h[k]
                offsets.append(row)
                labels.append(f"{names[k]}{s}{tag}")

        for k in active:
            axis(k, 1.0, "h")
        if opts.step_check:
            for k in active:
                axis(k, 0.5, "h/2")
        for k, j in self._mixed_pairs(active, rho):
            for sk, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                row = np.zeros(len(space))
                row[k], row[j] = sk * h[k], sj * h[j]
                offsets.append(row)
                labels.append(f"{names[k]}{'+' if sk > 0 else '-'}h,"
                              f"{names[j]}{'+' if sj > 0 else '-'}h")
        offsets = np.array(offsets)
        values = mu + offsets
        design = make_design(space, values,
                             step=(PARAMETER, h, {"long_name": "finite-difference step h_k"}))
        # Coordinates, not data variables: everything in runs with a realization dim is
        # taken for a solver output (base.output_names).
        design = design.assign_coords(
            offset=((REALIZATION, PARAMETER), offsets,
                    {"long_name": "stencil offset from the input means"}),
            stencil=(REALIZATION, np.array(labels, dtype=object)))
        design.attrs.update(step_fraction=opts.step, step_check=int(opts.step_check))
        return design

    def _mixed_pairs(self, active, rho):
        opts = self.options
        want = opts.mixed_derivatives
        if want == "auto":
            every = opts.variance == "second-order"
            if opts.order == 1 and not every:
                return []
            return [(k, j) for k in active for j in active
                    if k < j and (every or rho[k, j] != 0)]
        return [(k, j) for k in active for j in active if k < j] if want else []

    # --------------------------------------------------------------- analyze
    def analyze(self, design, runs):
        opts = self.options
        names = [str(p) for p in design[PARAMETER].values]
        s = design[INPUT_STD].values
        rho = design[INPUT_CORRELATION].values
        st = _Stencil(design)
        if opts.variance == "second-order" and any(
                rho[k, j] != 0 for k in st.active for j in st.active if k < j):
            raise _independence_error()
        # The realized offsets, not the nominal ones: mu + h is rounded to a float, and the
        # divided differences below are exact for quadratics only with the true spacing.
        x = design[INPUTS].values
        x = np.vstack([x - x[st.centre], np.full((1, x.shape[1]), np.nan)])
        ok = ok_mask(runs)
        with_hessian = opts.order == 2 or opts.variance == "second-order" or bool(st.pairs)

        data, warnings = {}, self._failure_warnings(runs, st, names)
        mu3 = np.where(s > 0, design[INPUT_SKEWNESS].values * s**3, 0.0)
        mu4 = np.where(s > 0, design[INPUT_KURTOSIS].values * s**4, 0.0)
        for out in output_names(runs):
            dims = runs[out].dims[1:]
            y = np.where(ok.reshape((-1,) + (1,) * len(dims)), runs[out].values, np.nan)
            y = np.concatenate([y, np.full((1,) + y.shape[1:], np.nan)])  # row -1: missing
            g, hess, computed = st.derivatives(y, x, 1)
            f0 = y[st.centre]
            sk = s[(slice(None),) + (None,) * len(dims)]
            mean = f0.copy()
            if opts.order == 2:
                # Only terms with a weight: a failed mixed point of an uncorrelated pair
                # (mixed derivatives forced on) must not make the mean NaN.
                weight = np.outer(s, s) * rho
                used = np.where((computed & (weight != 0))[(...,) + (None,) * len(dims)],
                                hess, 0.0)
                mean = f0 + 0.5 * np.einsum("kj...,kj->...", used, weight)
            if opts.variance == "first-order":
                gs = g * sk
                var = np.einsum("k...,kj,j...->...", gs, rho, gs)
            else:
                var = _second_order_variance(g, hess, computed, s, mu3, mu4, dims)
            std = np.sqrt(np.maximum(var, 0.0))
            data[out] = ((STATISTIC, *dims), np.stack([mean, var, std, f0]))
            data[f"{out}_gradient"] = ((PARAMETER, *dims), g, {
                "long_name": f"d{out}/dx_k at the input means",
                UNITS: _per_param(runs[out].attrs.get(UNITS, ""))})
            if with_hessian:
                data[f"{out}_hessian"] = ((PARAMETER, PARAMETER_J, *dims), hess, {
                    "long_name": f"d2{out}/dx_k dx_j at the input means (NaN: not computed)",
                    UNITS: _per_param(runs[out].attrs.get(UNITS, ""), 2)})
            if st.checked:
                g2, h2, _ = st.derivatives(y, x, 0.5)
                floor = st.rounding_floor(y, x)
                k = np.arange(len(names))
                diag, diag2 = hess[k, k], h2[k, k]
                dg = _relative_change(g, g2, floor[0])
                dc = _relative_change(diag, diag2, floor[1])
                data[f"{out}_gradient_change"] = ((PARAMETER, *dims), dg, {
                    "long_name": "|g(h) - g(h/2)| / max(|g(h)|, |g(h/2)|)", UNITS: "1"})
                data[f"{out}_curvature_change"] = ((PARAMETER, *dims), dc, {
                    "long_name": "|H_kk(h) - H_kk(h/2)| / max(...)", UNITS: "1"})
                # A derivative only matters if its term moves the output by more than a
                # millionth of its spread; others may wobble without harming anything.
                terms = [("gradient", dg, sk * np.abs(g))]
                if opts.order == 2 or opts.variance == "second-order":
                    terms.append(("curvature", dc, 0.5 * sk**2 * np.abs(diag)))
                for what, change, size in terms:
                    warnings += self._stability_warnings(out, runs, dims, names, what,
                                                         change, size, std)
        stats = xr.Dataset(data, coords={STATISTIC: LABELS})
        stats = stats.assign_coords({d: runs[d] for d in runs.coords
                                     if d != REALIZATION and d in stats.dims})

        warnings += cv_warnings(design[INPUT_CV].values, st.active, names, opts.cv_warning)
        warnings += self._omitted_mixed_warnings(st, rho, names)
        for msg in warnings:
            pywarnings.warn(msg, AccuracyWarning, stacklevel=2)
        stats = finish_statistics(stats, design, runs, self.name, warnings)
        stats.attrs.update(order=opts.order, step=float(design.attrs.get("step_fraction",
                                                                         opts.step)),
                           variance=opts.variance, step_check=int(st.checked),
                           mixed_derivatives=len(st.pairs))
        return stats

    @classmethod
    def report(cls, view):
        """The expansion's order and variance, and each input's contribution g_k² s_k² to
        an output's variance; the runs are stencil points, not draws."""
        attrs = view.stats.attrs
        order, variance = attrs.get("order", "?"), attrs.get("variance", "")
        text = f"Taylor order {order}" + (f", {variance} variance" if variance else "")
        runs = int(attrs.get(SOLVER_RUNS, 0))
        return MethodReport(
            description=f"Taylor expansion, order {order}, {runs} run{'' if runs == 1 else 's'}"
                        + (", second-order variance" if variance == "second-order" else ""),
            columns=[Column("expansion", lambda out, focus: text)],
            sensitivities=lambda out: contributions(view, out))

    # -------------------------------------------------------------- warnings
    def _stability_warnings(self, out, runs, dims, names, what, change, size, std):
        tol = self.options.step_tolerance
        with np.errstate(invalid="ignore"):
            bad = (change > tol) & (size > 1e-6 * std)
        msgs = []
        for k in np.flatnonzero(bad.reshape(len(names), -1).any(axis=1)):
            worst = np.where(bad[k], change[k], -np.inf)
            at = np.unravel_index(np.argmax(worst), worst.shape)
            where = ""
            if dims:
                where = " at " + ", ".join(
                    f"{d} = {_label(runs[d].values[i])}" if d in runs.coords else f"{d}[{i}]"
                    for d, i in zip(dims, at))
            msgs.append(f"the {what} of '{out}' with respect to '{names[k]}' is not "
                        f"step-stable: it changes by {change[k][at]:.3g} (relative) when the "
                        f"step is halved{where}; the function is not smooth on the scale of "
                        f"the step, so the Taylor estimates are doubtful (try a smaller step "
                        f"or monte-carlo)")
        return msgs

    def _failure_warnings(self, runs, st, names):
        status = runs[STATUS].values
        msgs = []
        for r in np.flatnonzero(status != STATUS_OK):
            label = str(st.labels[r])
            if r == st.centre:
                hurt = "every estimate is NaN"
            elif r in st.half_rows:
                hurt = "only the step check of that input is lost"
            elif r in st.pair_rows:
                hurt = "that mixed derivative and the estimates using it are NaN"
            else:
                hurt = "that input's derivatives and the estimates using them are NaN"
            why = "did not run" if status[r] == STATUS_PENDING else \
                (str(runs[MESSAGE].values[r]) or "no message")
            msgs.append(f"realization {r} (stencil point {label}) failed: {why}; {hurt}")
        return msgs

    def _omitted_mixed_warnings(self, st, rho, names):
        opts = self.options
        missing = [(k, j) for k in st.active for j in st.active
                   if k < j and (k, j) not in st.pairs]
        msgs = []
        corr = [(k, j) for k, j in missing if rho[k, j] != 0]
        if opts.order == 2 and corr:
            msgs.append("mixed derivatives were not computed for the correlated pairs "
                        + ", ".join(f"({names[k]}, {names[j]})" for k, j in corr)
                        + ": the mean omits their terms 1/2 H_kj s_k s_j rho_kj")
        if opts.variance == "second-order" and missing:
            msgs.append("mixed derivatives were not computed: the second-order variance "
                        "omits the cross terms 1/2 H_kj^2 s_k^2 s_j^2")
        return msgs


def contributions(view, out: str) -> Sensitivity | None:
    """Each input's contribution g_k² s_k² to the variance of ``out`` (from the gradient at
    the input means), None without a gradient."""
    stats = view.stats
    gradient = f"{out}_gradient"
    if gradient not in stats or INPUT_STD not in stats:
        return None
    terms = ((stats[gradient] * stats[INPUT_STD]) ** 2).expand_dims(
        {"index": ["contribution g_k² s_k²"]}, axis=1).transpose(PARAMETER, "index", ...)
    units = view.units(out)
    return Sensitivity(
        title="Taylor: contribution of each input to the variance",
        values=terms, quantity=f"variance [({units})²]" if units else "variance",
        note=contribution_note(stats))


def contribution_note(stats) -> str:
    """What the per-input terms g_k² s_k² leave out of the variance, if anything."""
    rho = stats[INPUT_CORRELATION].values if INPUT_CORRELATION in stats else None
    if rho is not None and np.any(rho[~np.eye(rho.shape[0], dtype=bool)] != 0):
        return "correlated inputs: cross terms 2 g_k g_j s_k s_j rho_kj apart"
    if stats.attrs.get("variance") == "second-order":
        return "second-order variance: the curvature terms apart"
    return ""


def cv_warnings(cv, active, names, limit) -> list[str]:
    """Warnings about the inputs (indices ``active``) whose C.V. exceeds ``limit``."""
    msgs = []
    for k in active:
        if not np.isfinite(cv[k]):
            msgs.append(f"input '{names[k]}' has mean 0, so no C.V. tells how far Taylor's "
                        f"expansion reaches; check the estimate against monte-carlo")
        # 1e-9: a C.V. given as exactly the limit comes back from the moments rounded
        elif cv[k] > limit * (1 + 1e-9):
            msgs.append(f"input '{names[k]}' has C.V. {cv[k]:.3g} > {limit:g}: Taylor "
                        f"expansions lose accuracy at large C.V. (seed 000 sec. 4.1 keeps C.V. "
                        f"<= 0.15); check against monte-carlo")
    return msgs


class _Stencil:
    """Which realization holds which stencil point, read back from the design's offsets."""

    def __init__(self, design):
        h = design["step"].values
        self.labels = design["stencil"].values
        n = h.size
        self.active = np.flatnonzero(h > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(h > 0, design["offset"].values / np.where(h > 0, h, 1.0), 0.0)
        u = np.round(u * 2) / 2
        self.centre = None
        axis, pairs = {}, {}
        for r, row in enumerate(u):
            nz = np.flatnonzero(row)
            if nz.size == 0 and self.centre is None:
                self.centre = r
            elif nz.size == 1:
                axis.setdefault((nz[0], row[nz[0]]), r)
            elif nz.size == 2:
                pairs.setdefault((nz[0], nz[1], row[nz[0]] > 0, row[nz[1]] > 0), r)
        if self.centre is None:
            raise StudyError("the design has no realization at the input means; it was not "
                             "planned by the taylor method", key="method.kind")
        # -1 picks the NaN row appended to every output: a missing point gives NaN, not 0.
        self.axis = {frac: (np.array([axis.get((k, frac), -1) for k in range(n)]),
                            np.array([axis.get((k, -frac), -1) for k in range(n)]))
                     for frac in (1.0, 0.5)}
        self.checked = bool(self.active.size) and all(
            (k, f) in axis for k in self.active for f in (0.5, -0.5))
        self.half_rows = {axis[(k, f)] for k in self.active for f in (0.5, -0.5)
                          if (k, f) in axis}
        self.pairs = {}
        for k in self.active:
            for j in self.active:
                quad = [pairs.get((k, j, a, b), -1)
                        for a, b in ((True, True), (True, False), (False, True), (False, False))]
                if k < j and -1 not in quad:
                    self.pairs[(k, j)] = quad
        self.pair_rows = {r for quad in self.pairs.values() for r in quad}
        self.n = n

    def derivatives(self, y, x, frac):
        """Gradient (n, *dims), Hessian (n, n, *dims) and which Hessian entries exist."""
        n = self.n
        plus, minus = self.axis[frac]
        col = (slice(None),) + (None,) * (y.ndim - 1)
        k = np.arange(n)
        a, b = x[plus, k][col], -x[minus, k][col]  # realized steps forward and back
        f0 = y[self.centre]
        with np.errstate(divide="ignore", invalid="ignore"):
            fwd, back = (y[plus] - f0) / a, (f0 - y[minus]) / b
            # Divided differences on unequal spacing: exact for quadratics whatever a and b.
            g = (b * fwd + a * back) / (a + b)
            curv = 2 * (fwd - back) / (a + b)
        idle = np.setdiff1d(k, self.active)  # zero std: the input never moves
        g[idle] = 0.0
        curv[idle] = 0.0
        hess = np.full((n, n) + y.shape[1:], np.nan)
        computed = np.zeros((n, n), dtype=bool)
        hess[k, k] = curv
        computed[k, k] = True
        hess[idle, :] = hess[:, idle] = 0.0
        computed[idle, :] = computed[:, idle] = True
        if frac == 1.0:
            for (i, j), (pp, pm, mp, mm) in self.pairs.items():
                den = (x[pp, i] - x[mp, i]) * (x[pp, j] - x[pm, j])
                hess[i, j] = hess[j, i] = (y[pp] - y[pm] - y[mp] + y[mm]) / den
                computed[i, j] = computed[j, i] = True
        return g, hess, computed

    def rounding_floor(self, y, x):
        """Size of gradient and curvature that rounding of f alone can produce at h/2.

        Below it a derivative is noise (a linear output's curvature, say), and its relative
        change carries no information: (f+ - f-)/2h errs by up to NOISE F / h, and
        (f+ - 2 f0 + f-)/h^2 by 4 NOISE F / h^2, F the largest |f| on the stencil.
        """
        plus, minus = self.axis[0.5]
        k = np.arange(self.n)
        h = (0.5 * (x[plus, k] - x[minus, k]))[(slice(None),) + (None,) * (y.ndim - 1)]
        with np.errstate(invalid="ignore"):
            span = np.fmax(np.fmax(np.abs(y[plus]), np.abs(y[minus])), np.abs(y[self.centre]))
        with np.errstate(divide="ignore", invalid="ignore"):
            return NOISE * span / h, 4 * NOISE * span / h**2


def _second_order_variance(g, hess, computed, s, mu3, mu4, dims):
    """Var of g.d + 1/2 d'Hd for independent d with central moments s^2, mu3, mu4."""
    col = (slice(None),) + (None,) * len(dims)
    n = s.size
    k = np.arange(n)
    diag = hess[k, k]
    off = np.where((computed & ~np.eye(n, dtype=bool))[(...,) + (None,) * len(dims)],
                   hess, 0.0)
    s2 = s**2
    return (np.sum((g * s[col]) ** 2, axis=0)
            + np.sum(g * diag * mu3[col], axis=0)
            + 0.25 * np.sum(diag**2 * (mu4 - s2**2)[col], axis=0)
            + 0.5 * np.einsum("kj...,k,j->...", off**2, s2, s2))


def _relative_change(d1, d2, floor):
    """|d1 - d2| / max(|d1|, |d2|, rounding floor); 0 where both are 0."""
    den = np.fmax(np.fmax(np.abs(d1), np.abs(d2)), np.nan_to_num(floor, nan=0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den == 0, 0.0, np.abs(d1 - d2) / den)


def _per_param(units: str, power: int = 1) -> str:
    per = "parameter unit" if power == 1 else "parameter unit^2"
    return f"{units} per {per}" if units else f"1 per {per}"
