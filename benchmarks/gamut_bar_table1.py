"""Seed 002's Table 1 and Figs. 21-32 from the 20 gamut-bar studies (studies/gamut_bar).

Runs every study (``load_study`` + ``run_study(force=True)``; the stochastic ones — 30
realizations of random fields — on 2 workers, the deterministic ones in-process), or with
``--reuse`` reads the results already on disk (running only the missing ones). A study
stopped by failing realizations (more than its ``max_failure_fraction``, 0.1 by default) is
run once more to the end from a copy of its file with ``max_failure_fraction = 1.0``, into
``<stem>_all_realizations.nc`` beside its result (``--no-rerun``: not), and the report uses
that one: its means are over the realizations that finished, and it says how many. Then

- prints the gamut-bar report (``solvers/gamut_bar/report.py``): Table 1 with our mean n'
  and K' beside the seed's numbers, the spread over the realizations, the failure strains,
  the mean monotonic curve against the deterministic one;
- writes the figures into docs/figures/gamut_bar_*.png;
- writes the tables into BENCHMARKS.md (section ``gamut-bar-table1``) and into
  docs/gamut_bar_results.md (the section between ``<!-- begin gamut-bar-table1 -->`` and
  ``<!-- end gamut-bar-table1 -->``; the rest of that file is left alone).

This script is the source of the numbers in both files: rerun it after the solver changes.

    python benchmarks/gamut_bar_table1.py [--reuse] [--workers 2] [--only PATTERN]
"""

from __future__ import annotations

import argparse
import fnmatch
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks._record import FIGURES, command, machine, write_section  # noqa: E402
from solvers.gamut_bar import GamutBarSolver  # noqa: E402
from solvers.gamut_bar.report import (STRAINS, comparison_tables, identify,  # noqa: E402
                                      mean_curve, report)
from uqflow.errors import UqflowError  # noqa: E402
from uqflow.execute import run_study  # noqa: E402
from uqflow.store import open_result  # noqa: E402
from uqflow.study import load_study  # noqa: E402

STUDIES = ROOT / "studies" / "gamut_bar"
RESULTS_MD = ROOT / "docs" / "gamut_bar_results.md"
SECTION = "gamut-bar-table1"


def _rerun_copy(path: Path, folder: Path) -> Path:
    """The study file with ``max_failure_fraction = 1.0`` (every realization runs, failures
    recorded) and its result beside the original as ``<stem>_all_realizations.nc``."""
    study = load_study(path)
    out = study.output_path.with_name(study.output_path.stem + "_all_realizations.nc")
    text = path.read_text()
    text = re.sub(r"(?m)^max_failure_fraction\s*=.*\n", "", text)
    text = re.sub(r"(?m)^\[execution\]\s*\n",
                  "[execution]\n# benchmarks/gamut_bar_table1.py: run every realization\n"
                  "max_failure_fraction = 1.0\n", text, count=1)
    text = re.sub(r"(?m)^path\s*=.*$", f'path = "{out.as_posix()}"', text)
    copy = folder / path.name
    copy.write_text(text)
    return copy


def _complete(result: Path) -> bool:
    if not result.exists():
        return False
    tree = open_result(result)
    return bool(int(tree.attrs.get("complete", 0))) and "statistics" in tree.children


def _current(result: Path, study_file: Path) -> bool:
    """The result exists and was run from the study file's present text (not a stale one)."""
    if not result.exists():
        return False
    return str(open_result(result).attrs.get("study", "")) == study_file.read_text()


def _run(path: Path, workers: int) -> tuple[str, float]:
    start = time.perf_counter()
    try:
        run_study(load_study(path), workers=workers, force=True, show_progress=False)
        state = "ran"
    except UqflowError as exc:          # StudyFailed: the runs so far are on disk
        state = f"stopped: {exc}"
    return state, time.perf_counter() - start


def run_all(paths: list[Path], reuse: bool, workers: int, rerun: bool) -> list[dict]:
    """Run (or reuse) every study; a study stopped by failing realizations is run once more
    to the end (``max_failure_fraction = 1``) into ``<stem>_all_realizations.nc``, which the
    report then uses."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, path in enumerate(paths, 1):
            study = load_study(path)
            stochastic = study.spec.method.kind != "nominal"
            out = study.output_path
            row = {"study": path.name, "result": out, "kind": "stochastic" if stochastic
                   else "deterministic", "workers": workers if stochastic else 0,
                   "wall": None, "rerun": None}
            if reuse and _current(out, path):
                row["state"] = "reused"
            else:
                if reuse and out.exists():
                    print(f"{out.name}: run from another version of {path.name}: rerun")
                print(f"[{k}/{len(paths)}] {path.name} ...", end=" ", flush=True)
                row["state"], row["wall"] = _run(path, row["workers"])
                print(f"{row['wall']:.1f} s, {row['state'][:160]}", flush=True)
            if rerun and not _complete(out):
                copy = _rerun_copy(path, Path(tmp))
                full = load_study(copy).output_path
                if reuse and _complete(full) and _current(full, copy):
                    row["rerun"] = {"result": full, "state": "reused", "wall": None}
                else:
                    print("    rerun to the end (max_failure_fraction = 1) ...", end=" ",
                          flush=True)
                    state, wall = _run(copy, row["workers"])
                    row["rerun"] = {"result": full, "state": state, "wall": wall}
                    print(f"{wall:.1f} s, {state[:160]}", flush=True)
            rows.append(row)
    return rows


def _runs_table(rows: list[dict], trees: dict) -> str:
    lines = ["| study | kind | workers | wall [s] | ok runs | state |",
             "|---|---|---:|---:|---:|---|"]

    def line(name, kind, workers, result, wall, state):
        tree = trees.get(result)
        res = identify(tree) if tree is not None else None
        ok = f"{res.n_ok}/{res.total}" if res is not None else "–"
        if wall is None and tree is not None:
            wall = float(tree.attrs.get("elapsed_time", np.nan))
        if state in ("ran", "reused"):
            state = (state + ", " if state == "reused" else "") + (
                "complete" if tree is not None and int(tree.attrs.get("complete", 0))
                else "incomplete")
        wall_text = "–" if wall is None or not np.isfinite(wall) else f"{wall:.1f}"
        return (f"| {name} | {kind} | {workers} | {wall_text} | {ok} | "
                f"{state.replace('|', '/')} |")

    for row in rows:
        lines.append(line(row["study"], row["kind"], row["workers"], row["result"],
                          row["wall"], row["state"]))
        if row["rerun"]:
            r = row["rerun"]
            lines.append(line(f"↳ {row['study']} with max_failure_fraction = 1 "
                              f"(`{r['result'].name}`)", row["kind"], row["workers"],
                              r["result"], r["wall"], r["state"]))
    return "\n".join(lines)


def localisation(r) -> str:
    """How concentrated the strain is at failure: the most strained local bond against the
    bar strain, and that bond's R against the realization's mean R."""
    bs, fs, R = r.values("bond_strain"), r.values("failure_strain"), r.values("R")
    if bs is None or fs is None or bs.ndim != 2:
        return ""
    ok = np.isfinite(fs) & np.isfinite(bs).all(axis=1)
    if not ok.any():
        return ""
    bs, fs = bs[ok], fs[ok]
    ratio = bs.max(axis=1) / fs
    text = (f" At failure the most strained local bond has {np.median(ratio):.1f}× the bar "
            f"strain (median; {ratio.min():.1f}–{ratio.max():.1f}×), and a median "
            f"{np.median((bs > 2 * fs[:, None]).sum(axis=1)):.0f} of {bs.shape[1]} bonds "
            f"exceed twice the bar strain")
    if R is not None and R.ndim == 2:
        R = R[ok]
        j = np.argmax(bs, axis=1)
        rel = R[np.arange(j.size), j] / R.mean(axis=1) - 1
        text += (f"; that bond's R lies {-100 * np.median(rel):.0f} % below the realization's "
                 f"mean R (median; R's C.V. along the bar {np.mean(R.std(1) / R.mean(1)):.3f})")
    return text + "."


def observations(results) -> list[str]:
    """What the numbers say, computed (so a rerun after a solver change stays true)."""
    notes = []
    det = {(r.case, r.loading, r.grid): r for r in results if not r.stochastic}
    for r in results:
        if not r.stochastic or r.n_ok == 0:
            continue
        fs = r.values("failure_strain")
        fs = fs[np.isfinite(fs)] if fs is not None else np.array([])
        d = det.get((r.case, r.loading, r.grid)) or det.get((r.case, r.loading, "uniform"))
        d_fs = float(d.values("failure_strain")[0]) if d is not None and d.n_ok else np.nan
        if r.loading == "monotonic" and fs.size:
            _, count = mean_curve(r.runs, STRAINS)
            reach = ", ".join(f"{c} reach ε = {e:g}" for e, c in zip(STRAINS, count))
            notes.append(f"{r.case}, {r.grid} grid, monotonic: the {r.n_ok} realizations fail "
                         f"at ε = {fs.min():.3g} … {fs.max():.3g} (mean {fs.mean():.3g}, "
                         f"median {np.median(fs):.3g}) against {d_fs:.3g} for the "
                         f"deterministic bar ({fs.mean() / d_fs:.0%}); {reach}."
                         + localisation(r))
        if r.loading == "cyclic":
            n = r.values("n_prime")
            n = n[np.isfinite(n)] if n is not None else np.array([])
            d_n = float(d.values("n_prime")[0]) if d is not None and d.n_ok else np.nan
            if n.size:
                notes.append(f"{r.case}, {r.grid} grid, cyclic: n' = {n.mean():.4g} ± "
                             f"{n.std(ddof=1) if n.size > 1 else 0:.2g} over {n.size} "
                             f"realizations ({n.min():.4g} … {n.max():.4g}), deterministic "
                             f"{d_n:.4g}; failure after the cycles at ε = {fs.mean():.3g} "
                             f"(mean) against {d_fs:.3g}." if fs.size else "")
        if r.n_ok < r.total:
            status = np.asarray(r.runs["status"].values).astype(str)
            msgs = np.asarray(r.runs["message"].values).astype(str) \
                if "message" in r.runs else np.array([""] * r.total)
            bad = np.flatnonzero(status != "ok")
            notes.append(f"{r.name}: {bad.size} of {r.total} realizations did not finish "
                         f"({', '.join(sorted(set(status[bad])))}); first: "
                         f"{msgs[bad[0]][:200] or '(no message)'}")
    return [n for n in notes if n]


def _write_results_md(body: str) -> None:
    block = f"<!-- begin {SECTION} -->\n{body.strip()}\n<!-- end {SECTION} -->"
    if RESULTS_MD.exists():
        text = RESULTS_MD.read_text()
    else:
        text = ("# Deformation-gamut bar: results against seed 002\n\n"
                "Generated sections; each says which script writes it.\n")
    pattern = re.compile(rf"<!-- begin {re.escape(SECTION)} -->.*?<!-- end "
                         rf"{re.escape(SECTION)} -->", re.S)
    text = pattern.sub(lambda _: block, text) if pattern.search(text) else \
        text.rstrip() + "\n\n" + block + "\n"
    RESULTS_MD.write_text(text)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--reuse", action="store_true",
                   help="read the results on disk; run only the missing ones")
    p.add_argument("--workers", type=int, default=2, help="workers of the stochastic studies")
    p.add_argument("--only", default="*", help="glob on the study file names")
    p.add_argument("--no-rerun", action="store_true",
                   help="do not rerun a study stopped by failing realizations to the end")
    p.add_argument("--no-write", action="store_true", help="print only")
    args = p.parse_args(argv)

    paths = sorted(x for x in STUDIES.glob("*.toml") if fnmatch.fnmatch(x.name, args.only))
    started = time.perf_counter()
    rows = run_all(paths, args.reuse, args.workers, rerun=not args.no_rerun)
    total = time.perf_counter() - started
    trees, tree_list = {}, []
    for row in rows:
        for result in (row["result"], (row["rerun"] or {}).get("result")):
            if result is not None and result.exists():
                trees[result] = open_result(result)
        # the report reads the study run to the end when the original stopped
        used = (row["rerun"] or {}).get("result") or row["result"]
        if used in trees:
            tree_list.append(trees[used])
    # the seed's figures only: the bar with its field realizations is each result's own
    text, pngs = report(tree_list, FIGURES, figures=not args.no_write,
                        solver_class=GamutBarSolver, bar_fields=False)
    print(text)
    for png in pngs:
        print(f"figure: {png.relative_to(ROOT)}")
    if args.no_write:
        return 0

    results = [r for r in map(identify, tree_list) if r is not None]
    tables = "\n\n".join(t.markdown() for t in comparison_tables(tree_list))
    notes = "\n".join(f"- {n}" for n in observations(results))
    ran = sum(1 for r in rows if r["wall"] is not None) \
        + sum(1 for r in rows if r["rerun"] and r["rerun"]["wall"] is not None)
    elapsed = sum(float(tr.attrs.get("elapsed_time", 0.0)) for tr in tree_list)
    how = (f"{ran} study runs in {total / 60:.1f} min (stochastic on {args.workers} workers, "
           f"deterministic in-process)" if ran else
           f"results read from disk (`--reuse`; the studies took {elapsed / 60:.1f} min, "
           f"stochastic on {args.workers} workers, deterministic in-process)")

    def figures_md(prefix: str) -> str:
        main_figs = [f for f in pngs if f.name.endswith("_monotonic.png")
                     or f.name.endswith("_constants.png")]
        others = [f for f in pngs if f not in main_figs]
        md = "\n\n".join(f"![{f.stem}]({prefix}{f.name})" for f in main_figs)
        if others:
            md += "\n\nMore figures: " + ", ".join(f"[{f.stem}]({prefix}{f.name})"
                                                    for f in others)
        return md

    body = f"""
The 20 studies of `studies/gamut_bar` (seed 002 section 4: materials M1, M2 as printed and
M2 with n_ro = 21; monotonic and cyclic loading; one deterministic run (`nominal`) or 30
realizations of Weibull-perturbed random fields (`kl-weibull`); uniform or stochastic grid
of 500 local bonds), {how}, compared with seed 002's Table 1 and Figs. 21-32 by
`solvers/gamut_bar/report.py` (the same text `uqflow report results/gamut_bar/*.nc` prints
once the solver's report hook is attached). Seed numbers: `tests/data/seed_tables.toml`.
A study stopped by failing realizations (more than 10 %) is run once more with
`max_failure_fraction = 1` (row ↳, result `*_all_realizations.nc`) and reported from that run.

{_runs_table(rows, trees)}

{tables}

Observations (computed by the script):

{notes}
"""
    write_section(SECTION, "Deformation-gamut bar: seed 002 Table 1 and Figs. 21-32",
                  body + "\n" + figures_md("docs/figures/"))
    _write_results_md(
        f"## Seed 002 Table 1, failure and mean curves (all 20 studies)\n\n"
        f"Written by `{command()}` on {machine()}; do not edit by hand: rerun the script.\n"
        + body + "\n" + figures_md("figures/"))
    print("written: BENCHMARKS.md (gamut-bar-table1), docs/gamut_bar_results.md,",
          f"{len(pngs)} figures in docs/figures/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
