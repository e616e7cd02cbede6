"""The deterministic run: every input at its mean, every random field at its mean."""

from __future__ import annotations

import json

import numpy as np
import xarray as xr

from uqflow.fields import germ_variable
from uqflow.layout import REALIZATION, STATISTIC
from uqflow.methods.base import (PropagationMethod, failure_warning, finish_statistics,
                                 make_design, ok_mask, output_names, register_method)
from uqflow.methods.kl_weibull import field_attrs, fields_described
from uqflow.report import MethodReport


@register_method("nominal")
class Nominal(PropagationMethod):
    """One run at the inputs' means and the fields' means: the deterministic reference."""

    accepts_fields = True
    needs_inputs = False

    def plan(self, space, fields, seed):
        self.check(space, fields)
        design = make_design(space, space.means[None, :])
        if fields:
            design.attrs["fields"] = json.dumps({f.name: germ_variable(f.name) for f in fields})
        for field in fields or []:
            design.attrs.update(field_attrs(field))
            # Zero germs: the KL sum vanishes and every field equals its mean exactly.
            design[germ_variable(field.name)] = (
                (REALIZATION, f"mode_{germ_variable(field.name)[5:]}"),
                np.zeros((1, field.n_modes)))
        return design

    def analyze(self, design, runs):
        ok = ok_mask(runs)
        data = {}
        for out in output_names(runs):
            value = runs[out].values[0] if ok[0] else np.full(runs[out].shape[1:], np.nan)
            zero = np.zeros_like(value)
            data[out] = ((STATISTIC, *runs[out].dims[1:]), np.stack([value, zero, zero]))
        stats = xr.Dataset(data, coords={STATISTIC: ["mean", "variance", "std"]})
        stats = stats.assign_coords({d: runs[d] for d in runs.coords
                                     if d != REALIZATION and d in stats.dims})
        stats.attrs.update(fields_described(design))
        return finish_statistics(stats, design, runs, self.name, failure_warning(runs))

    @classmethod
    def report(cls, view):
        """The deterministic run in words; it is no draw, and its std is 0 by construction."""
        fields = " and the random fields" if view.stats.attrs.get("fields") else ""
        return MethodReport(description=f"Nominal run: one run with the inputs{fields} at "
                                        f"their means")
