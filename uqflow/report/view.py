"""``ResultView``: one result as the report layer, a method's report hook and a solver's see it."""

from __future__ import annotations

import warnings
from functools import cached_property

import numpy as np
import xarray as xr

from uqflow.errors import StudyError
from uqflow.layout import (LONG_NAME, METHOD, RUNS_GROUP, STATISTIC, STATISTICS_GROUP, STATUS,
                           STUDY_NAME, sample_mask)
from uqflow.report import tables
from uqflow.registry import method_registry
from uqflow.report.contributions import MethodReport


class ReportHookWarning(UserWarning):
    """A method's report hook raised: the report goes on without the method's part."""


class ResultView:
    """A result's groups and attributes, with the lookups every part of a report needs."""

    def __init__(self, tree: xr.DataTree):
        self.attrs = dict(tree.attrs)
        self.runs = tree[RUNS_GROUP].to_dataset() if RUNS_GROUP in tree.children else None
        self.stats = tree[STATISTICS_GROUP].to_dataset() \
            if STATISTICS_GROUP in tree.children else None
        self.design = tree["design"].to_dataset() if "design" in tree.children else None
        if self.runs is None and self.stats is None:
            raise StudyError("has neither a 'runs' nor a 'statistics' group: not a uqflow "
                             "result file")
        self.study = str(self.attrs.get(STUDY_NAME, "study"))
        source = self.stats.attrs if self.stats is not None else self.attrs
        self.method = str(source.get(METHOD, self.attrs.get(METHOD, "?")))

    @property
    def outputs(self) -> list[str]:
        """The outputs analysed: every statistics variable with a ``statistic`` dim."""
        if self.stats is None:
            return []
        return [str(v) for v in self.stats.data_vars if STATISTIC in self.stats[v].dims]

    @cached_property
    def method_report(self) -> MethodReport:
        """What the result's method adds (``PropagationMethod.report``); empty for a method
        that is not installed here or adds nothing."""
        if self.stats is None:
            return MethodReport()
        try:
            method = method_registry.get(self.method)
        except StudyError:
            return MethodReport()
        try:
            return method.report(self) or MethodReport()
        except Exception as exc:  # a broken hook (a third party's) must not cost the report
            warnings.warn(f"the report hook of method '{self.method}' failed "
                          f"({type(exc).__name__}: {exc}); the report shows what every "
                          f"result has", ReportHookWarning, stacklevel=2)
            return MethodReport()

    def units(self, output: str) -> str:
        return tables.units_of(output, self.stats, self.runs)

    def long_name(self, output: str) -> str:
        """The output in words (its ``long_name`` attribute), else its name."""
        for ds in (self.stats, self.runs):
            if ds is not None and output in ds and ds[output].attrs.get(LONG_NAME):
                return str(ds[output].attrs[LONG_NAME])
        return output

    @property
    def description(self) -> str:
        """The method in words for titles and legends (the method's own, else its name)."""
        return self.method_report.description or f"method {self.method}"

    def statistic(self, output: str, label: str) -> xr.DataArray | None:
        return tables.statistic(self.stats, output, label)

    def focus(self, output: str) -> dict[str, int]:
        return tables.focus_point(self.stats, output)

    def where(self, focus: dict[str, int]) -> str:
        return tables.where(self.stats, focus)

    def sample_values(self, output: str) -> np.ndarray | None:
        """The output in the runs that are draws from the inputs' distribution (realization
        first; ``uqflow.layout.sample_mask``), None without runs."""
        if self.runs is None or output not in self.runs or STATUS not in self.runs:
            return None
        return np.asarray(self.runs[output].values, dtype=float)[sample_mask(self.runs)]

    def title(self, output: str, what: str, focus: dict | None = None) -> str:
        where = f" at {self.where(focus)}" if focus else ""
        return f"{self.study}: {output}{where}\n{what}"
