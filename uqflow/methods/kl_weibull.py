"""KL–Weibull: Monte Carlo over random fields (seed 002, eqs. 26–27) and scalar inputs.

Every realization gets the scalar inputs as Monte Carlo (rule "random") would sample them,
and for every random field its KL germs: ``germ_<field>`` (realization, ``mode_<field>``),
drawn from ``germ_seed(seed, realization, field_index)`` so that realization i's germs do not
depend on how many realizations the design has. The solver turns germs into field values
through ``uqflow.fields.FieldSample``; the design stores germs, never field values.
Statistics are Monte Carlo's (germs are not outputs). See docs/fields.md.
"""

from __future__ import annotations

import json

import numpy as np
from pydantic import Field

from uqflow.errors import StudyError
from uqflow.fields import germ_seed, germ_variable
from uqflow.methods.base import make_design, register_method
from uqflow.layout import REALIZATION, SOLVER_RUNS, WARNINGS
from uqflow.methods.monte_carlo import (MonteCarlo, SampleStatisticsOptions,
                                        convergence_figure, failure_exceedance_figures,
                                        failure_lines, sample_notes)
from uqflow.report import FigureSpec, MethodReport
from uqflow.sampling import unit_hypercube


class KLWeibullOptions(SampleStatisticsOptions):
    realizations: int = Field(30, ge=1, description="number of realizations (seed 002: 30)")
    min_samples: int = Field(10, ge=2, description="never stop on target before this many")

    # What MonteCarlo's analyze/enough read under their own names.
    @property
    def samples(self) -> int:
        return self.realizations

    @property
    def rule(self) -> str:
        return "random"


def _field_name(field) -> str | None:
    if isinstance(field, dict):
        return field.get("name")
    return getattr(field, "name", None)


def _safe(name: str) -> str:
    """``germ_variable(name)`` without its ``germ_`` prefix (netCDF-safe)."""
    return germ_variable(name)[len("germ_"):]


@register_method("kl-weibull")
class KLWeibull(MonteCarlo):
    """Random fields by KL expansion with symmetric-Weibull germs (seed 002), plus scalar MC."""

    Options = KLWeibullOptions
    accepts_fields = True

    def check(self, space, fields):
        if not fields:
            raise StudyError("kl-weibull needs at least one random field ([[fields]] table); "
                             "use monte-carlo for scalar inputs only", key="fields")
        seen: dict[str, str] = {}
        for i, f in enumerate(fields):
            name = _field_name(f)
            if not isinstance(name, str) or not name:
                raise StudyError("every field needs a name", key=f"fields[{i}].name")
            var = germ_variable(name)
            if var in seen:
                raise StudyError(f"fields '{seen[var]}' and '{name}' share the design "
                                 f"variable '{var}' (names differ only in punctuation)",
                                 key=f"fields[{i}].name")
            seen[var] = name

    def plan(self, space, fields, seed):
        self.check(space, fields)
        n = self.options.realizations
        u = unit_hypercube("random", n, len(space), seed)
        variables, attrs, mapping = {}, {}, {}
        for k, field in enumerate(fields):
            safe = _safe(field.name)
            germs = np.empty((n, field.n_modes))
            for i in range(n):
                germs[i] = field.spec.germ.draw(
                    field.n_modes, np.random.default_rng(germ_seed(seed, i, k)))
            var = germ_variable(field.name)
            mapping[field.name] = var
            variables[var] = (((REALIZATION, f"mode_{safe}"), germs,
                               {"field": field.name, "germ": field.spec.germ.kind,
                                "long_name": f"KL germs of random field '{field.name}'"}))
            attrs.update(field_attrs(field))
        design = make_design(space, space.from_unit_hypercube(u), **variables)
        design.attrs["rule"] = "random"
        design.attrs["realizations"] = n
        design.attrs["fields"] = json.dumps(mapping)
        design.attrs.update(attrs)
        return design

    def analyze(self, design, runs):
        stats = super().analyze(design, runs)
        described = fields_described(design)
        stats.attrs.update(described)
        warnings = [v for k, v in described.items() if k.endswith("_warning") and v]
        if warnings:
            old = stats.attrs.get(WARNINGS, "")
            stats.attrs[WARNINGS] = "\n".join([w for w in [old, *warnings] if w])
        return stats

    @classmethod
    def report(cls, view):
        """Which error the interval rests on, and each output's convergence; the runs are
        draws of the fields and inputs, so the report shows their scatter as Monte Carlo's."""
        stats = view.stats
        try:
            names = list(json.loads(stats.attrs.get("fields", "{}")))
        except (TypeError, ValueError):
            names = []
        runs = int(stats.attrs.get(SOLVER_RUNS, 0))
        fields = f"random field{'' if len(names) == 1 else 's'} {', '.join(names)}" \
            if names else "random fields"
        return MethodReport(
            description=f"Monte Carlo over the {fields} (KL expansion), {runs} "
                        f"run{'' if runs == 1 else 's'}",
            runs_are_draws=True, notes=sample_notes(view) + failure_lines(stats),
            figures=[FigureSpec("convergence", convergence_figure)]
            + failure_exceedance_figures(stats))


def fields_described(design) -> dict:
    """The design's attributes that describe its random fields (``field_attrs``), which the
    statistics carry so that a report lists the fields among the uncertain inputs."""
    return {k: v for k, v in design.attrs.items() if k == "fields" or k.startswith("field_")}


def field_attrs(field) -> dict:
    """Attributes ``field_<safe name>_*`` describing a random field: what it drives, its
    kernel, correlation length, KL modes and captured variance, germs and amplitude."""
    safe = _safe(field.name)
    spec = field.spec
    out = {
        f"field_{safe}_captured_fraction": float(field.captured_fraction),
        f"field_{safe}_modes": int(field.n_modes),
        f"field_{safe}_kernel": spec.kernel,
        f"field_{safe}_correlation_length": float(spec.correlation_length),
        f"field_{safe}_amplitude": float(field.amplitude),
        f"field_{safe}_germ": (spec.germ.kind if spec.germ.kind == "gaussian" else
                               f"symmetric-weibull(scale={spec.germ.scale:g}, "
                               f"shape={spec.germ.shape:g})"),
        f"field_{safe}_parameters": ", ".join(spec.targets),
        f"field_{safe}_kl": field.basis.method,
    }
    if field.warning:
        out[f"field_{safe}_warning"] = field.warning
    return out
