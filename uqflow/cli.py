"""Command line: ``uqflow run | validate | report | list``.

Exit codes: 0 done; 1 a study stopped mid-run (too many failed realizations, the result file
could not be written, a dask task died; the runs so far are on disk); 2 a user error found
before anything ran (study, scene, result path, scheduler), printed as one line
``uqflow: error: <file>: <key>: <reason>``; 3 an internal error (a bug in uqflow or a solver
outside a realization), printed as one line ``uqflow: internal error: ...``; 130
interrupted. No command prints a Python traceback unless ``UQFLOW_DEBUG=1`` is set.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

from uqflow.errors import AccuracyWarning, StudyError, UqflowError

EXIT_USAGE = 2
EXIT_FAILED = 1
EXIT_INTERNAL = 3


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="uqflow", description="Uncertainty propagation through "
                                "particle solvers for solid mechanics.")
    sub = p.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run a study file and write its result and figures")
    run.add_argument("study", type=Path)
    run.add_argument("-o", "--output", type=Path, default=None, metavar="PATH",
                     help="write the result here instead of the study's [output] path "
                     "(figures beside it; --resume and --force apply to it)")
    run.add_argument("--workers", type=int, default=None,
                     help="dask worker processes on this machine (0: run in this process)")
    run.add_argument("--scheduler", default=None,
                     help="address of an existing dask scheduler, e.g. tcp://10.0.0.5:8786")
    mode = run.add_mutually_exclusive_group()
    mode.add_argument("--resume", action="store_true",
                      help="finish an interrupted study without redoing finished realizations")
    mode.add_argument("--force", action="store_true", help="overwrite an existing result")
    run.add_argument("--no-figures", action="store_true", help="write no PNG figures")
    run.add_argument("--quiet", action="store_true", help="no progress bar")

    val = sub.add_parser("validate", help="check study files without running them")
    val.add_argument("studies", type=Path, nargs="+")

    rep = sub.add_parser("report", help="print the table and redraw the figures of results; "
                         "a solver may add a comparison across several results")
    rep.add_argument("results", type=Path, nargs="+")
    rep.add_argument("--figures", type=Path, default=None,
                     help="folder for the PNG figures (default: beside the result)")
    rep.add_argument("--no-figures", action="store_true")
    rep.add_argument("--time", type=float, default=None, metavar="SECONDS",
                     help="the output time of a solver's comparison tables (MPM: default the "
                          "last output time)")
    rep.add_argument("--reference", default=None, metavar="NAME",
                     help="the result the comparison measures the others against (its file "
                          "name without .nc; MPM: default the smallest standard error)")

    sub.add_parser("list", help="list the registered solvers and propagation methods")
    return p


def _run(args) -> int:
    from uqflow import report
    from uqflow.execute import run_study
    from uqflow.study import MAX_WORKERS, load_study

    if args.workers is not None and not 0 <= args.workers <= MAX_WORKERS:
        raise StudyError(f"must be between 0 and {MAX_WORKERS} (docs/study-files.md, Limits), "
                         f"got {args.workers}", key="--workers")
    study = load_study(args.study)
    with warnings.catch_warnings():
        # Methods also return their warnings in the result; print each once, below the table.
        warnings.simplefilter("ignore", AccuracyWarning)
        outcome = run_study(study, workers=args.workers, scheduler=args.scheduler,
                            resume=args.resume, force=args.force, show_progress=not args.quiet,
                            output=args.output)
    if outcome.resumed:
        print(f"resumed: {outcome.resumed} realizations were already done")
    tree = report.open_result(outcome.path)
    print(report.summary_table(tree))
    for message in outcome.warnings:
        print(f"warning: {message}", file=sys.stderr)
    print(f"result: {outcome.path}")
    figures = study.spec.output.figures and not args.no_figures
    folder = report.figure_folder(outcome.path)
    if figures:
        for fig in report.write_figures(tree, folder):
            print(f"figure: {fig}")
    text, extra = report.solver_report([tree], folder, figures=figures)
    if text:
        print(text)
    for fig in extra:
        print(f"figure: {fig}")
    return 0


def _validate(args) -> int:
    from uqflow.study import load_study

    for path in args.studies:
        study = load_study(path)
        print(f"{path}: ok ({study.spec.solver}, {study.spec.method.kind}, "
              f"{len(study.space)} random inputs, outputs {', '.join(study.outputs)})")
    return 0


def _report(args) -> int:
    from uqflow import report
    from uqflow.report_levels import cost_comparison

    trees = []
    for path in args.results:
        tree = report.open_result(path)
        trees.append(tree)
        if len(args.results) > 1:
            print(f"== {path}")
        print(report.summary_table(tree))
        notes = tree["statistics"].attrs.get("warnings", "") \
            if "statistics" in tree.children else ""
        for message in filter(None, notes.split("\n")):
            print(f"warning: {message}", file=sys.stderr)
        if not args.no_figures:
            folder = args.figures or report.figure_folder(path)
            for fig in report.write_figures(tree, folder):
                print(f"figure: {fig}")
    text, figures = report.solver_report(trees, args.figures or
                                         report.figure_folder(args.results[0]).parent,
                                         figures=not args.no_figures, time=args.time,
                                         reference=args.reference)
    if text:
        print(text)
    for fig in figures:
        print(f"figure: {fig}")
    text, figures = cost_comparison(trees, args.figures or
                                    report.figure_folder(args.results[0]).parent,
                                    figures=not args.no_figures)
    if text:
        print(text)
    for fig in figures:
        print(f"figure: {fig}")
    return 0


def _list(args) -> int:
    from uqflow.methods import method_registry
    from uqflow.solver import solver_registry

    print("solvers:")
    for name, doc in solver_registry.describe().items():
        print(f"  {name:<16} {doc}")
    print("methods:")
    for name, doc in method_registry.describe().items():
        print(f"  {name:<16} {doc}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    handler = {"run": _run, "validate": _validate, "report": _report, "list": _list}
    try:
        return handler[args.command](args)
    except StudyError as exc:
        if os.environ.get("UQFLOW_DEBUG"):
            raise
        print(f"uqflow: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except UqflowError as exc:
        if os.environ.get("UQFLOW_DEBUG"):
            raise
        print(f"uqflow: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print("uqflow: interrupted; finish with --resume", file=sys.stderr)
        return 130
    except Exception as exc:  # last line of defence: a bug must still read as one line
        if os.environ.get("UQFLOW_DEBUG"):
            raise
        print(f"uqflow: internal error: {type(exc).__name__}: {' '.join(str(exc).split())} "
              f"(a bug: rerun with UQFLOW_DEBUG=1 for the traceback and report it)",
              file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
