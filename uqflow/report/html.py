"""One self-contained HTML report per result (docs/results.md, "The HTML report"): the summary
(its tables as HTML tables, the rest as preformatted text), every figure embedded as a base64
PNG, the solver's text and figures, and the study file the result was run from. It refers to
no other file and no URL, so it opens offline and can be mailed on its own."""

from __future__ import annotations

import base64
import html
import tempfile
from pathlib import Path

import xarray as xr

from uqflow.layout import STUDY_TEXT, STUDY_TEXT_OMITTED
from uqflow.report.framework_figures import write_figures
from uqflow.report.summary import summary_blocks
from uqflow.report.tables import Table
from uqflow.report.view import ResultView

STYLE = """
body { font-family: sans-serif; margin: 1.5em auto; max-width: 80em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.6em 0; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.6em; }
th { background: #eef2f7; } td.number { text-align: right; font-variant-numeric: tabular-nums; }
pre { background: #f7f7f7; padding: 0.6em; white-space: pre-wrap; }
figure { margin: 1em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #555; }
"""


def _table(table: Table) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in table.header)
    body = []
    for row in table.rows:
        cells = "".join(f'<td class="number">{html.escape(c)}</td>' if i in table.right
                        else f"<td>{html.escape(c)}</td>" for i, c in enumerate(row))
        body.append(f"<tr>{cells}</tr>")
    return f"<table>\n<thead><tr>{head}</tr></thead>\n<tbody>\n" + "\n".join(body) + \
        "\n</tbody>\n</table>"


def _blocks(blocks: list) -> list[str]:
    """Runs of text lines as one <pre> each, tables as <table>."""
    parts, text = [], []

    def flush():
        while text and not text[-1].strip():
            text.pop()
        if any(line.strip() for line in text):
            parts.append("<pre>" + html.escape("\n".join(text)) + "</pre>")
        text.clear()

    for block in blocks:
        if isinstance(block, Table):
            flush()
            parts.append(_table(block))
        elif text or str(block).strip():
            text.append(str(block))
    flush()
    return parts


def _figure(path: Path) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    name = html.escape(Path(path).name)
    return (f'<figure><img alt="{name}" data-file="{name}" '
            f'src="data:image/png;base64,{data}"><figcaption>{name}</figcaption></figure>')


def write_html(tree: xr.DataTree, path: Path, solver_text: str = "",
               solver_figures=(), figures=None) -> Path:
    """Write the HTML report of a result to ``path`` and return it: the summary, the result's
    figures (``figures``: PNG paths already written by ``write_figures``; None: drawn here into
    a temporary folder), the solver's text and figures (``solver_report``), and the study
    file. Every image is embedded; the file refers to nothing outside it."""
    view = ResultView(tree)
    path = Path(path)
    title = f"uqflow report: {view.study}"
    parts = [f"<h1>{html.escape(title)}</h1>"]
    if view.stats is not None:
        parts.append(f"<p>{html.escape(view.description)}</p>")
    parts += ["<h2>Summary: outputs, notes, cost, inputs</h2>", *_blocks(summary_blocks(tree))]
    with tempfile.TemporaryDirectory() as scratch:
        drawn = list(figures) if figures is not None else write_figures(tree, Path(scratch))
        if drawn:
            parts.append("<h2>Figures</h2>")
            parts += [_figure(p) for p in drawn]
    if solver_text or solver_figures:
        parts.append("<h2>What the solver adds</h2>")
        if solver_text:
            parts.append("<pre>" + html.escape(solver_text) + "</pre>")
        parts += [_figure(p) for p in solver_figures]
    study = str(view.attrs.get(STUDY_TEXT, ""))
    if study or view.attrs.get(STUDY_TEXT_OMITTED):
        parts.append("<h2>The study file</h2>")
        parts.append("<pre>" + html.escape(study or str(view.attrs[STUDY_TEXT_OMITTED]))
                     + "</pre>")
    page = ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            f"<title>{html.escape(title)}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n"
            + "\n".join(parts) + "\n</body>\n</html>\n")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page, encoding="utf-8")
    return path
