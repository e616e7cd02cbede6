"""Command line: ``uqflow run | validate | report | list``.

Exit codes: 0 done; 1 a study stopped mid-run (too many failed realizations, the result file
could not be written, a dask task died; the runs so far are on disk); 2 a user error found
before anything ran (study, scene, result path, scheduler), printed as one line
``uqflow: error: <file>: <key>: <reason>``; 3 an internal error (a bug in uqflow or a solver
outside a realization), printed as one line ``uqflow: internal error: ...``; 130
interrupted (Ctrl-C: one line, also under dask); 141 the output pipe was closed (below). No
command prints a Python traceback unless ``UQFLOW_DEBUG=1`` is set.

A command-line mistake (an unknown option, ``--workers abc``, ``--resume --force``) is one
line ``uqflow: error: <option>: <reason>``, exit 2, not argparse's usage block.

A closed output pipe (``uqflow list | head -2``) ends the command quietly with exit 141, the
code a shell reports for a process that SIGPIPE ended, as ``cat`` or ``ls`` would give: a
pipeline under ``set -o pipefail`` still sees that the output was cut short. A study whose
summary is cut short this way has already written its result file.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import warnings
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from uqflow.errors import AccuracyWarning, StudyError, UqflowError

EXIT_USAGE = 2
EXIT_FAILED = 1
EXIT_INTERNAL = 3
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 128 + signal.SIGPIPE  # 141, as a shell reports a process SIGPIPE ended


class _OneLineParser(argparse.ArgumentParser):
    """argparse's errors as one line ``uqflow: error: <option>: <reason>``, exit 2."""

    def error(self, message: str):
        message = " ".join(message.split())
        message = re.sub(r"^argument ([^:]+): ", lambda m: f"{m.group(1).split('/')[-1]}: ",
                         message)
        self.exit(EXIT_USAGE, f"uqflow: error: {message} (see {self.prog} --help)\n")


def _version() -> str:
    try:
        return version("uqflow")
    except PackageNotFoundError:  # a source tree that was never installed
        return "unknown (not installed)"


def _parser() -> argparse.ArgumentParser:
    p = _OneLineParser(prog="uqflow", description="Uncertainty propagation through "
                       "particle solvers for solid mechanics.")
    p.add_argument("--version", action="version", version=f"uqflow {_version()}")
    sub = p.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run a study file and write its result and figures")
    run.add_argument("study", type=Path, help="the study file (TOML) to run")
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
    _add_set_option(run)

    val = sub.add_parser("validate", help="check study files without running them")
    val.add_argument("studies", type=Path, nargs="+", metavar="study",
                     help="study files (TOML); each is checked and gets one line, ok or its "
                          "error")
    _add_set_option(val)

    rep = sub.add_parser("report", help="print the table and redraw the figures of results; "
                         "a solver may add a comparison across several results")
    rep.add_argument("results", type=Path, nargs="+", metavar="result",
                     help="result files (.nc) written by uqflow run")
    rep.add_argument("--figures", type=Path, default=None,
                     help="folder for the PNG figures (default: beside the result)")
    rep.add_argument("--no-figures", action="store_true", help="write no PNG figures")
    rep.add_argument("--html", action="store_true",
                     help="also write one self-contained HTML report per result "
                          "(<stem>_report.html beside it, or in the --figures folder)")
    rep.add_argument("--time", type=float, default=None, metavar="SECONDS",
                     help="the output time of a solver's comparison tables (MPM: default the "
                          "last output time)")
    rep.add_argument("--reference", default=None, metavar="NAME",
                     help="the result the comparison measures the others against (its file "
                          "name without .nc; MPM: default the smallest standard error)")

    sub.add_parser("list", help="list the registered solvers and propagation methods")

    srv = sub.add_parser("serve", help="serve a study's solver as a UM-Bridge model "
                         "(docs/umbridge.md)")
    srv.add_argument("study", type=Path, help="the study file (TOML): its solver, scene, "
                     "inputs (the model's input vector) and outputs; or a scene file with "
                     "--solver")
    srv.add_argument("--solver", default=None, metavar="NAME",
                     help="serve a scene file (not a study) with this solver: every parameter "
                     "it has is an input, every output an output")
    srv.add_argument("--host", default="127.0.0.1",
                     help="address to listen on (default 127.0.0.1, this machine only)")
    srv.add_argument("--port", type=int, default=4242, help="port (0: any free one; the "
                     "line printed at start says which)")
    srv.add_argument("--workers", type=int, default=1,
                     help="evaluations run at once, each in a worker process of its own")
    _add_set_option(srv)
    return p


def _add_set_option(command) -> None:
    command.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                         dest="overrides",
                         help="override a key of the study file, e.g. method.samples=64, "
                              "method.kind=pce, inputs.0.cv=0.2 (a TOML value; a bare word "
                              "is a string); repeatable (docs/study-files.md, Overrides)")


def _overrides(args) -> dict:
    """The ``--set`` options as {key: value}, in the order given (a key set twice: the
    last value)."""
    from uqflow.study import parse_override

    return dict(parse_override(text) for text in args.overrides)


def _run(args) -> int:
    from uqflow import report
    from uqflow.execute import run_study
    from uqflow.study import MAX_WORKERS, load_study

    if args.workers is not None and not 0 <= args.workers <= MAX_WORKERS:
        raise StudyError(f"must be between 0 and {MAX_WORKERS} (docs/study-files.md, Limits), "
                         f"got {args.workers}", key="--workers")
    study = load_study(args.study, overrides=_overrides(args))
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
    written = report.write_figures(tree, folder) if figures else []
    for fig in written:
        print(f"figure: {fig}")
    text, extra = report.solver_report([tree], folder, figures=figures)
    if text:
        print(text)
    for fig in extra:
        print(f"figure: {fig}")
    if figures:  # the HTML report beside the figures, with the solver's part
        html = report.write_html(tree, folder.with_name(outcome.path.stem + "_report.html"),
                                 solver_text=text, solver_figures=extra, figures=written)
        print(f"report: {html}")
    return 0


def _validate(args) -> int:
    """Check every file given, one line each (``ok`` on stdout, the error on stderr); exit 2
    if any failed."""
    from uqflow.study import load_study

    failed = 0
    overrides = _overrides(args)
    for path in args.studies:
        try:
            study = load_study(path, overrides=overrides)
        except StudyError as exc:
            print(f"uqflow: error: {exc}", file=sys.stderr)
            failed += 1
            continue
        print(f"{path}: ok ({study.spec.solver}, {study.spec.method.kind}, "
              f"{_uncertain_inputs(study)}, outputs {', '.join(study.outputs)})")
    return EXIT_USAGE if failed else 0


def _uncertain_inputs(study) -> str:
    """'3 random inputs' and, when the study has them, ', 2 random fields (E, rho)'."""
    n = len(study.space)
    text = f"{n} random input{'' if n == 1 else 's'}"
    if study.fields:
        names = ", ".join(f.name for f in study.fields)
        text += f", {len(study.fields)} random field{'' if len(study.fields) == 1 else 's'} " \
                f"({names})"
    return text


def _report(args) -> int:
    """Tables of every result, then figures. A figures folder that cannot be written still
    gets the tables printed, then one line naming the folder, exit 2."""
    from uqflow import report
    from uqflow.layout import STATISTICS_GROUP, WARNINGS
    from uqflow.methods import compare_results as cost_comparison

    if args.figures is not None and not args.no_figures and args.figures.exists() \
            and not args.figures.is_dir():
        raise StudyError(f"{args.figures}: is a file, not a folder for the figures",
                         key="--figures")
    cannot: list[str] = []  # why figures could not be written, once it happened

    def draw(folder, make):
        """``make(figures)`` with figures on until one failed; on a write failure the same
        again without figures, so its text is still printed."""
        if args.no_figures or cannot:
            return make(False)
        try:
            return make(True)
        except OSError as exc:
            where = exc.filename or folder
            cannot.append(f"{where}: cannot write the figures: {exc.strerror or exc}")
            return make(False)

    trees, drawn = [], []  # the results, and the figures written of each
    for path in args.results:
        tree = report.open_result(path)
        trees.append(tree)
        if len(args.results) > 1:
            print(f"== {path}")
        try:
            print(report.summary_table(tree))
        except StudyError as exc:  # a result file that is not what uqflow writes
            raise exc.located(str(path)) from None
        notes = tree[STATISTICS_GROUP].attrs.get(WARNINGS, "") \
            if STATISTICS_GROUP in tree.children else ""
        for message in filter(None, notes.split("\n")):
            print(f"warning: {message}", file=sys.stderr)
        folder = args.figures or report.figure_folder(path)
        drawn.append(draw(folder, lambda on: report.write_figures(tree, folder) if on else []))
        for fig in drawn[-1]:
            print(f"figure: {fig}")
    shared = args.figures or report.figure_folder(args.results[0]).parent
    added = []  # (text, figures) of the solver's report, then of the methods' comparison
    for make in (lambda on: report.solver_report(trees, shared, figures=on, time=args.time,
                                                 reference=args.reference),
                 lambda on: cost_comparison(trees, shared, figures=on)):
        text, figures = draw(shared, make)
        added.append((text, figures))
        if text:
            print(text)
        for fig in figures:
            print(f"figure: {fig}")
    for path, tree, written in zip(args.results, trees, drawn) if args.html else ():
        html = report.write_html(tree, (args.figures or Path(path).parent)
                                 / f"{Path(path).stem}_report.html", solver_text=added[0][0],
                                 solver_figures=added[0][1], figures=written or None)
        print(f"report: {html}")
    if cannot:
        print(f"uqflow: error: {cannot[0]} (the tables above are complete; choose a folder "
              f"with --figures or leave them out with --no-figures)", file=sys.stderr)
        return EXIT_USAGE
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


def _serve(args) -> int:
    from uqflow.study import MAX_WORKERS
    from uqflow.umbridge_server import serve

    if not 1 <= args.workers <= MAX_WORKERS:
        raise StudyError(f"must be between 1 and {MAX_WORKERS}, got {args.workers}",
                         key="--workers")
    if not 0 <= args.port <= 65535:
        raise StudyError(f"must be a port number from 0 to 65535, got {args.port}",
                         key="--port")
    serve(args.study, host=args.host, port=args.port, workers=args.workers,
          overrides=_overrides(args), solver=args.solver,
          ready=lambda line: print(line, flush=True))
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    handler = {"run": _run, "validate": _validate, "report": _report, "list": _list,
               "serve": _serve}
    try:
        code = handler[args.command](args)
        sys.stdout.flush()  # a closed pipe shows here, not at exit
        return code
    except BrokenPipeError:
        return _closed_pipe()
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
        resume = "; finish with --resume" if args.command == "run" else ""
        print(f"uqflow: interrupted{resume}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:  # last line of defence: a bug must still read as one line
        if os.environ.get("UQFLOW_DEBUG"):
            raise
        print(f"uqflow: internal error: {type(exc).__name__}: {' '.join(str(exc).split())} "
              f"(a bug: rerun with UQFLOW_DEBUG=1 for the traceback and report it)",
              file=sys.stderr)
        return EXIT_INTERNAL


def _closed_pipe() -> int:
    """The reader of stdout went away: end quietly. What is still buffered for stdout cannot
    be written; pointing stdout at /dev/null keeps Python's flush at exit from reporting it."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):  # stdout without a file descriptor (a test's capture)
        pass
    return EXIT_BROKEN_PIPE


if __name__ == "__main__":
    sys.exit(main())
