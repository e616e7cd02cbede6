"""The report layer: tables and figures of a result, for the framework, its methods and its
solvers alike (docs/results.md, docs/architecture.md).

- ``summary_table(tree)``: the text ``uqflow run`` and ``uqflow report`` print;
  ``write_figures(tree, folder)``: the PNG figures; ``solver_report(trees, folder)``: what the
  results' solver adds (its ``Solver.report``); ``write_html(tree, path)``: all of it in one
  self-contained HTML file.
- ``scene_ran(attrs)``: the scene a result ran (study text or checked scene file, with the
  recorded ``--set`` overrides), or why it cannot be had: for a solver's scene map.
- ``display_units(values, units)``: the SI prefix a figure shows a quantity in (GPa, mm, µs).
- ``ResultView``: a result as a report sees it; ``MethodReport`` (with ``Column``,
  ``Sensitivity``, ``FigureSpec``): what a method's ``report`` hook returns.
- Plumbing for anyone's tables and figures: ``Table``, ``grid``, ``number``, ``seconds``,
  ``new_figure``, ``save_figure``, ``figure_path``, ``safe_file_name``, ``figure_folder``,
  ``axis_label``, ``scientific_ticks``, ``colors``, ``coordinate``, ``input_label``,
  ``FigureWarning``.

The report layer names no method and no solver: what is particular to one comes from its hook.
"""

from uqflow.report.contributions import Column, FigureSpec, MethodReport, Sensitivity
from uqflow.report.figures import (FigureWarning, axis_label, colors, coordinate,
                                   figure_folder, figure_path, input_label, new_figure,
                                   safe_file_name, save_figure, scientific_ticks)
from uqflow.report.framework_figures import (exceedance_curve, exceedance_log_figure,
                                             scatter_band, write_figures)
from uqflow.report.html import write_html
from uqflow.report.solver_hook import solver_report
from uqflow.report.scene import scene_ran
from uqflow.report.summary import summary_table
from uqflow.report.tables import (Table, focus_point, grid, number, seconds, statistic,
                                  units_of, where)
from uqflow.report.units import display_units
from uqflow.report.view import ReportHookWarning, ResultView
from uqflow.store import open_result

__all__ = ["Column", "FigureSpec", "MethodReport", "Sensitivity", "FigureWarning",
           "axis_label", "colors", "coordinate", "figure_folder", "figure_path", "input_label",
           "new_figure", "safe_file_name", "save_figure", "scientific_ticks", "open_result",
           "solver_report", "summary_table", "write_figures", "focus_point", "grid", "number",
           "seconds", "statistic", "units_of", "where", "ResultView", "ReportHookWarning", "Table",
           "display_units",
           "exceedance_curve", "exceedance_log_figure", "scatter_band", "write_html", "scene_ran"]
