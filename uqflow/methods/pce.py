"""Polynomial chaos expansion by regression (chaospy Hermite basis); docs/pce.md.

The design is a quasi-random, Latin hypercube or random set of points u in (0, 1)^d; the
independent standard normals z = Φ⁻¹(u) behind the inputs are stored with it (variable
``standard_normal``), and ``InputSpace.from_unit_hypercube`` maps the same u to the inputs
(z → correlated normals → marginal inverse CDFs). ``analyze`` regresses every output on
orthonormal Hermite polynomials of z (``pce_fit``), chooses the order by the leave-one-out
error, and reads mean, variance and Sobol' indices off the coefficients.
"""

from __future__ import annotations

import math
from typing import Literal

import chaospy
import numpy as np
import xarray as xr
from pydantic import Field, field_validator, model_validator
from scipy import stats as sps

from uqflow.errors import StudyError
from uqflow.inputs import UNIT_CLIP
from uqflow.methods.base import (MethodOptions, PropagationMethod, finish_statistics,
                                 make_design, ok_mask, output_names, register_method)
from uqflow.layout import (INPUT_CORRELATION, INPUT_STD, PARAMETER, REALIZATION, SOLVER_RUNS,
                           STATISTIC, STATUS, STATUS_PENDING, UNITS)
from uqflow.methods.monte_carlo import RULE_WORDS
from uqflow.methods.pce_fit import OVERSAMPLING, basis_size, select_expansion
from uqflow.methods.sobol import sobol_indices
from uqflow.report import Column, MethodReport
from uqflow.sampling import unit_hypercube

#: Highest total degree: Hermite polynomials of degree 20 reach 1e9 at |z| = 5, which the
#: design's tails sample, so the regression matrix loses most of float64's digits beyond.
MAX_ORDER = 20
#: Most basis terms: a design of OVERSAMPLING x 5000 runs makes a 10^4 x 5000 float64
#: regression matrix (0.4 GB) and its QR, the most one machine does in seconds.
MAX_BASIS_TERMS = 5000
SOBOL_LABELS = ["S1", "ST"]


class PCEOptions(MethodOptions):
    # order before max_order and samples: their checks read it.
    order: int | Literal["loo"] = Field(
        "loo", description='total degree, or "loo": the order <= max_order with the smallest '
                           'leave-one-out error')
    max_order: int = Field(5, ge=1, le=MAX_ORDER, description='highest order "loo" tries')
    samples: int | None = Field(None, ge=1, description=(
        "realizations; default OVERSAMPLING x the basis size of the (highest) order"))
    rule: Literal["sobol", "halton", "lhs", "random"] = "sobol"
    regression: Literal["auto", "least-squares", "omp"] = Field(
        "auto", description="least squares where runs >= 2 x basis terms, else OMP")
    basis: Literal["hermite", "askey"] = Field(
        "hermite", description='"askey": Legendre in u for uniform inputs (independent only)')
    loo_warning: float = Field(1e-2, gt=0, description="warn where the relative LOO error "
                                                       "exceeds this")

    @field_validator("order")
    @classmethod
    def _order_in_range(cls, order):
        if isinstance(order, int) and not 1 <= order <= MAX_ORDER:
            raise ValueError(f'must be "loo" or an integer in 1..{MAX_ORDER}, got {order}')
        return order

    @model_validator(mode="after")
    def _max_order_only_for_loo(self):
        return self.only_where("max_order", self.order == "loo",
                               f'order = "loo" only; order = {self.order} is fixed')

    @property
    def top_order(self) -> int:
        return self.max_order if self.order == "loo" else self.order

    @property
    def orders(self) -> list[int]:
        return list(range(1, self.max_order + 1)) if self.order == "loo" else [self.order]


def germ_dimensions(std: np.ndarray, correlation: np.ndarray) -> np.ndarray:
    """Indices of the standard variables the outputs can depend on: those of inputs with a
    spread, and of any input correlated with another (its z enters the others through the
    Cholesky factor). A constant independent input would only add dead terms to the basis."""
    coupled = np.any((correlation != np.eye(len(std))) & ~np.eye(len(std), dtype=bool), axis=0)
    return np.flatnonzero((np.asarray(std) > 0) | coupled)


@register_method("pce")
class PCE(PropagationMethod):
    """Polynomial chaos by regression on Hermite polynomials of the standard normal variables."""

    Options = PCEOptions

    def _samples(self, dimension: int) -> int:
        opts = self.options
        if opts.samples is not None:
            return opts.samples
        return OVERSAMPLING * basis_size(opts.top_order, dimension)

    def check(self, space, fields):
        super().check(space, fields)
        if len(space) == 0:
            raise StudyError("pce needs at least one uncertain input", key="inputs")
        opts = self.options
        d = len(germ_dimensions(space.stds, space.correlation))
        key = "method.max_order" if opts.order == "loo" else "method.order"
        terms = basis_size(opts.top_order, d)
        if terms > MAX_BASIS_TERMS:
            raise StudyError(f"order {opts.top_order} in {d} inputs has {terms:,} basis terms, "
                             f"more than the {MAX_BASIS_TERMS:,} pce fits (a lower order, or "
                             f"fewer uncertain inputs)", key=key)
        n = self._samples(d)
        smallest = OVERSAMPLING * basis_size(1, d)
        if n < smallest:
            raise StudyError(f"{n} runs are too few for {d} inputs: even the linear expansion "
                             f"({d + 1} terms) needs at least {smallest}", key="method.samples")
        if opts.regression == "least-squares" and n < OVERSAMPLING * terms:
            raise StudyError(f"{n} runs are too few for least squares of order "
                             f"{opts.top_order} in {d} inputs ({terms} terms): it needs at "
                             f"least {OVERSAMPLING * terms} ({OVERSAMPLING} x the terms); give "
                             f"more samples or regression = \"auto\" (sparse where the basis "
                             f"outgrows the runs)", key="method.samples")
        if opts.basis == "askey" and space.is_correlated:
            raise StudyError('basis = "askey" needs independent inputs (a uniform input '
                             'correlated through the Gaussian copula is not affine in its own '
                             'u); use basis = "hermite"', key="method.basis")
        if n > 10**7:
            raise StudyError(f"{n:,} realizations are more than the 10,000,000 a study may "
                             f"run", key="method.samples")

    def plan(self, space, fields, seed):
        self.check(space, fields)
        opts = self.options
        dims = germ_dimensions(space.stds, space.correlation)
        n = self._samples(len(dims))
        u = np.clip(unit_hypercube(opts.rule, n, len(space), seed), UNIT_CLIP, 1 - UNIT_CLIP)
        legendre = opts.basis == "askey"
        families = ["legendre" if legendre and inp.kind == "uniform" else "hermite"
                    for inp in space.inputs]
        design = make_design(
            space, space.from_unit_hypercube(u),
            standard_normal=((REALIZATION, PARAMETER), sps.norm.ppf(u),
                             {"long_name": "independent standard normal variables behind "
                                           "the inputs"}),
            standard_uniform=((REALIZATION, PARAMETER), u,
                              {"long_name": "the design's points in (0, 1)^d: Φ of "
                                            "standard_normal"}),
            basis_family=(PARAMETER, np.array(families, dtype=object),
                          {"long_name": "polynomial family of each input's germ: hermite "
                                        "in standard_normal, legendre in standard_uniform"}))
        design.attrs.update(rule=opts.rule, order=str(opts.order), max_order=opts.top_order,
                            regression=opts.regression, basis=opts.basis,
                            input_kinds=",".join(inp.kind for inp in space.inputs))
        return design

    def analyze(self, design, runs):
        opts = self.options
        names = [str(p) for p in design[PARAMETER].values]
        dims = germ_dimensions(design[INPUT_STD].values, design[INPUT_CORRELATION].values)
        rows = np.asarray(runs[REALIZATION].values, dtype=int)
        germs, marginals = _germs(design, rows, dims)
        ok = ok_mask(runs)
        n_total = int((runs[STATUS].values != STATUS_PENDING).sum())
        rule = design.attrs.get("rule", opts.rule)
        warnings = []
        if bool(np.any(design[INPUT_CORRELATION].values != np.eye(len(names)))):
            warnings.append("correlated inputs: the Sobol' indices are those of the "
                            "independent standard normal variables behind the inputs "
                            "(Gaussian copula, Cholesky order of the inputs), not of the "
                            "inputs themselves; mean and variance are unaffected")
        data = {}
        orders = opts.orders
        # runs hold the design's variables too (standard_normal ...): those are no outputs.
        for out in [o for o in output_names(runs) if o not in design.data_vars]:
            shape = runs[out].shape[1:]
            out_dims = runs[out].dims[1:]
            y = np.asarray(runs[out].values, float).reshape(len(rows), -1)
            good = ok & np.all(np.isfinite(y), axis=1)
            dropped = n_total - int(good.sum())
            if dropped:
                warnings.append(
                    f"{out}: {dropped} of {n_total} realizations failed or gave a non-finite "
                    f"value; the regression uses the other {int(good.sum())}, so the design "
                    f"is no longer a balanced {rule} set, and where the failures depend on "
                    f"the inputs the expansion extrapolates into the region they came from")
            fit = select_expansion(germs[good], y[good], orders, opts.regression, marginals) \
                if good.sum() >= OVERSAMPLING * (len(dims) + 1) else None
            data.update(self._output_block(out, out_dims, shape, fit, names, dims, orders))
            if fit is None:
                warnings.append(f"{out}: {int(good.sum())} usable realizations are too few "
                                f"for any expansion: its statistics are NaN")
                continue
            hint = "" if design.attrs.get("basis", opts.basis) == "askey" or not any(
                design[INPUT_STD].values[k] > 0 and str(f) == "uniform"
                for k, f in enumerate(design.attrs.get("input_kinds", "").split(","))) else \
                '; basis = "askey" (Legendre) fits uniform inputs far better'
            warnings += _fit_warnings(out, runs, out_dims, shape, fit, opts.loo_warning, hint)
        coords = {STATISTIC: ["mean", "variance", "std"], "sobol_index": SOBOL_LABELS,
                  PARAMETER: names, "pce_order": np.arange(1, max(orders) + 1)}
        stats = xr.Dataset(data, coords=coords)
        stats = stats.assign_coords({c: runs[c] for c in runs.coords
                                     if c not in coords and c != REALIZATION
                                     and c in stats.dims})
        for name in stats.data_vars:
            if name.endswith(("_sobol", "_loo_error", "_loo_by_order", "_order", "_terms",
                              "_multi_index")):
                stats[name].attrs[UNITS] = ""
        stats = finish_statistics(stats, design, runs, self.name, warnings)
        stats.attrs.update(rule=rule, order=str(opts.order), max_order=opts.top_order,
                           basis=design.attrs.get("basis", opts.basis),
                           regression=opts.regression, loo_warning=opts.loo_warning,
                           samples_ok=int(ok.sum()))
        return stats

    @classmethod
    def report(cls, view):
        """Each output's expansion (order, terms, leave-one-out error) in the table, and the
        Sobol' indices its coefficients give as sensitivities. The runs are shown as draws:
        the design's points are the rule's draws from the inputs' distribution, as Monte
        Carlo's with the same rule."""
        stats = view.stats
        order = str(stats.attrs.get("order", "?"))
        if order == "loo":
            order = f"chosen by leave-one-out up to {stats.attrs.get('max_order', '?')}"
        runs = int(stats.attrs.get(SOLVER_RUNS, 0))
        rule = RULE_WORDS.get(str(stats.attrs.get("rule", "")))
        return MethodReport(
            description=f"Polynomial chaos expansion, order {order}, {runs} "
                        f"run{'' if runs == 1 else 's'}" + (f" ({rule})" if rule else ""),
            runs_are_draws=True,
            columns=[Column("expansion (LOO error: relative to the variance)",
                            lambda out, focus: expansion_cell(stats, out, focus))],
            sensitivities=lambda out: expansion_indices(stats, out))

    @staticmethod
    def _output_block(out, out_dims, shape, fit, names, dims, orders):
        """The statistics variables of one output (NaN when ``fit`` is None)."""
        d, term = len(names), f"{out}_term"
        if fit is None:
            nan = np.full(shape, np.nan)
            moments = np.full((3, *shape), np.nan)
            sobol = np.full((2, d, *shape), np.nan)
            return {out: ((STATISTIC, *out_dims), moments),
                    f"{out}_sobol": (("sobol_index", PARAMETER, *out_dims), sobol),
                    f"{out}_loo_error": (out_dims, nan)}
        variance = fit.variance
        moments = np.stack([fit.mean, variance, np.sqrt(variance)]).reshape(3, *shape)
        first, total = fit.sobol()
        sobol = np.zeros((2, d, first.shape[1]))
        sobol[0, dims], sobol[1, dims] = first, total
        sobol[:, :, variance == 0] = np.nan
        multi = np.zeros((fit.indices.shape[0], d), dtype=np.int64)
        multi[:, dims] = fit.indices
        loo_by_order = np.full(max(orders), np.nan)
        loo_by_order[: fit.loo_by_order.size] = fit.loo_by_order
        return {
            out: ((STATISTIC, *out_dims), moments),
            f"{out}_sobol": (("sobol_index", PARAMETER, *out_dims),
                             sobol.reshape(2, d, *shape),
                             {"long_name": "first-order and total Sobol' indices of the "
                                           "standard variables, from the coefficients"}),
            f"{out}_loo_error": (out_dims, fit.loo_error.reshape(shape),
                                 {"long_name": "leave-one-out error relative to the sample "
                                               "variance"}),
            f"{out}_loo_by_order": (("pce_order",), loo_by_order,
                                    {"long_name": "leave-one-out error of each order tried, "
                                                  "variance-weighted over the output's points "
                                                  "(NaN: not tried)"}),
            f"{out}_order": ((), fit.order, {"long_name": "total degree chosen"}),
            f"{out}_terms": ((), fit.indices.shape[0],
                             {"long_name": "terms kept" + (" (sparse)" if fit.sparse else "")}),
            f"{out}_coefficients": ((term, *out_dims),
                                    fit.coefficients.reshape(-1, *shape),
                                    {"long_name": "coefficients of the orthonormal Hermite "
                                                  f"terms {out}_multi_index"}),
            f"{out}_multi_index": ((term, PARAMETER), multi,
                                   {"long_name": "degree of each input's standard variable "
                                                 "in each term"}),
        }


def expansion_cell(stats, out: str, focus: dict) -> str:
    """'order 3, 20 terms, LOO error 0.0012' ('-' for an output without a fit)."""
    if f"{out}_loo_error" not in stats or f"{out}_order" not in stats:
        return "-"
    loo = float(stats[f"{out}_loo_error"].isel(focus))
    return (f"order {int(stats[f'{out}_order'])}, {int(stats[f'{out}_terms'])} terms, "
            f"LOO error {loo:.2g}")


def expansion_indices(stats, out: str):
    """The Sobol' indices of ``out`` from the expansion's coefficients (exact for the
    expansion: no sampling error to show), None without them."""
    if f"{out}_sobol" not in stats:
        return None
    rho = stats[INPUT_CORRELATION].values if INPUT_CORRELATION in stats else None
    correlated = rho is not None and bool(np.any(rho != np.eye(rho.shape[0])))
    note = ("correlated inputs: indices of the independent standard normal variables behind "
            "the inputs (Gaussian copula, Cholesky order), not of the inputs themselves"
            if correlated else "")
    return sobol_indices(stats[f"{out}_sobol"], "Sobol' indices of the polynomial chaos "
                         "expansion", note=note)


def _germs(design, rows, dims):
    """The germ values (rows, dims) and the chaospy marginal each basis is orthonormal in."""
    families = design["basis_family"].values if "basis_family" in design else \
        np.array(["hermite"] * design.sizes[PARAMETER])
    z = np.asarray(design["standard_normal"].values, float)[rows]
    u = np.asarray(design["standard_uniform"].values, float)[rows] \
        if "standard_uniform" in design else sps.norm.cdf(z)
    legendre = families == "legendre"
    germs = np.where(legendre[None, :], u, z)[:, dims]
    marginals = [chaospy.Uniform(0, 1) if legendre[k] else chaospy.Normal(0, 1) for k in dims]
    return germs, marginals


def _fit_warnings(out, runs, out_dims, shape, fit, threshold, hint="") -> list[str]:
    """A warning naming the output and its worst point when the LOO error exceeds
    ``threshold``; one for outputs with zero variance."""
    warnings = []
    loo = fit.loo_error.reshape(shape) if shape else fit.loo_error.reshape(())
    if np.all(fit.variance == 0):
        warnings.append(f"{out} does not vary over the design: its Sobol' indices are NaN")
    bad = loo > threshold
    if np.any(bad):
        worst = np.unravel_index(int(np.argmax(loo)), shape) if shape else ()
        where = ", ".join(_coordinate_text(runs, dim, i) for dim, i in zip(out_dims, worst))
        count = f" ({int(bad.sum())} of {bad.size} points above {threshold:g})" if shape else ""
        # How much that point matters: a relative error where the output hardly scatters
        # misleads less than one at its largest scatter.
        variance = fit.variance.reshape(shape) if shape else fit.variance.reshape(())
        share = math.sqrt(float(variance[worst]) / float(np.max(variance))) \
            if shape and np.max(variance) > 0 else 1.0
        scatter = f", where its std is {100 * share:.2g} % of its largest" if share < 1 else ""
        warnings.append(
            f"{out}: LOO error {float(loo[worst]):.2g}{' at ' + where if where else ''}"
            f"{scatter}{count} "
            f"with order {fit.order}: the expansion does not fit; the output is likely not "
            f"smooth in the inputs there (yield onset, unloading, a kink): raise max_order or "
            f"samples, or trust monte-carlo there{hint}")
    return warnings


def _coordinate_text(runs, dim, index) -> str:
    if dim in runs.coords:
        value = runs[dim].values[index]
        units = runs[dim].attrs.get(UNITS, "")
        text = f"{value:.4g}" if isinstance(value, (float, np.floating)) else str(value)
        return f"{dim} = {text}{' ' + units if units else ''}"
    return f"{dim} index {index}"
