"""What a propagation method adds to the report of its results: the contract of
``PropagationMethod.report`` (docs/architecture.md, "The report layer").

The report layer draws and tabulates what every result has (the scatter of each output, its
histogram and exceedance curve, the inputs, the cost); a method adds what only it knows (an
interval column, a note on what a control variate bought, its sensitivity indices, a figure of
its levels) by returning a ``MethodReport`` from its ``report(view)`` classmethod. The report
layer never names a method.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import xarray as xr


@dataclass(frozen=True)
class Column:
    """A column of the summary table: ``cell(output, focus)`` is the text of an output's row
    at its row point ``focus`` (a dict dim -> index, {} for a scalar). In ``header``, ``u``
    stands for each row's unit (the table's 'unit u' column)."""

    header: str
    cell: Callable[[str, dict], str]
    right_aligned: bool = False


@dataclass(frozen=True)
class Sensitivity:
    """What each input contributes to an output's variance, as the method computed it.

    ``values`` has dims (``parameter``, ``index``, *the output's dims*): one entry per input
    and kind of index (``index`` labels such as "first order S1", "total ST", or one label
    for a linearization's g_k² s_k²); ``errors`` (same dims, or None) are half-widths of an
    interval whose meaning ``error_label`` gives ("95 % bootstrap half-width"). ``quantity``
    says what the numbers are ("fraction of the variance", "variance [GPa²]"). The report
    draws a bar chart per output (at its row point, or lines over a field's one dim) and a
    table."""

    title: str
    values: xr.DataArray
    quantity: str
    errors: xr.DataArray | None = None
    error_label: str = ""
    note: str = ""


@dataclass(frozen=True)
class FigureSpec:
    """A figure the method draws: ``draw(view, output)`` returns a matplotlib ``Figure``
    (``uqflow.report.new_figure``) or None where it does not apply; ``output`` is None for a
    figure of the whole result (``per_output = False``). Saved as ``<output>_<kind>.png``
    (or ``<kind>.png``)."""

    kind: str
    draw: Callable
    per_output: bool = True


@dataclass
class MethodReport:
    """A method's part of a result's report (every field optional).

    - ``description``: the method in words, for titles and legends ("random sampling,
      8 runs, a one-run surrogate as control variate").
    - ``runs_are_draws``: whether the ok runs (``uqflow.layout.sample_mask``) are draws from
      the inputs' distribution, so that their quantiles, histogram and exceedance curve
      describe the output's scatter; otherwise the report shows mean ± 1.96 std from the
      statistics, and says so.
    - ``columns``: summary-table columns after mean, std (and variance).
    - ``notes``: lines printed under the table (what a control variate bought, a level
      table); ``cost_details``: words appended to the cost line ("rule lhs").
    - ``sensitivities(output)``: a ``Sensitivity`` or None.
    - ``figures``: the method's own figures (a convergence trace, a level plot).
    """

    description: str = ""
    runs_are_draws: bool = False
    columns: list[Column] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    cost_details: list[str] = field(default_factory=list)
    sensitivities: Callable[[str], Sensitivity | None] | None = None
    figures: list[FigureSpec] = field(default_factory=list)
