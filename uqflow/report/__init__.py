"""The report layer: tables and figures of a result, for the framework, its methods and its
solvers alike (docs/results.md, docs/architecture.md).

- ``summary_table(tree)``: the text ``uqflow run`` and ``uqflow report`` print;
  ``write_figures(tree, folder)``: the PNG figures; ``solver_report(trees, folder)``: what the
  results' solver adds (its ``Solver.report``).
- ``ResultView``: a result as a report sees it; ``MethodReport`` (with ``Column``,
  ``Sensitivity``, ``FigureSpec``): what a method's ``report`` hook returns.
- Plumbing for anyone's tables and figures: ``grid``, ``number``, ``seconds``, ``new_figure``,
  ``save_figure``, ``figure_path``, ``safe_file_name``, ``figure_folder``, ``axis_label``,
  ``scientific_ticks``, ``colors``, ``coordinate``, ``input_label``, ``FigureWarning``.

The report layer names no method and no solver: what is particular to one comes from its hook.
"""

from uqflow.report.contributions import Column, FigureSpec, MethodReport, Sensitivity
from uqflow.report.figures import (FigureWarning, axis_label, colors, coordinate,
                                   figure_folder, figure_path, input_label, new_figure,
                                   safe_file_name, save_figure, scientific_ticks)
from uqflow.report.summary import open_result, solver_report, summary_table, write_figures
from uqflow.report.tables import focus_point, grid, number, seconds, statistic, units_of, where
from uqflow.report.view import ResultView

__all__ = ["Column", "FigureSpec", "MethodReport", "Sensitivity", "FigureWarning",
           "axis_label", "colors", "coordinate", "figure_folder", "figure_path", "input_label",
           "new_figure", "safe_file_name", "save_figure", "scientific_ticks", "open_result",
           "solver_report", "summary_table", "write_figures", "focus_point", "grid", "number",
           "seconds", "statistic", "units_of", "where", "ResultView"]
