"""uqflow: uncertainty propagation of material properties through particle solvers.

The Python API does everything the CLI does::

    import uqflow
    study = uqflow.load_study("studies/quickstart.toml")
    outcome = uqflow.run_study(study, workers=2)
    tree = uqflow.open_result(outcome.path)      # xarray.DataTree: runs, statistics
"""

import importlib

from uqflow.errors import AccuracyWarning, SceneError, SolverError, StudyError

__version__ = "0.1.0"

# The rest of the API is imported on first use (PEP 562): `uqflow --version`, `--help` and a
# Ctrl-C in the first second must not wait for (or print a traceback from) scipy, xarray and
# chaospy being imported. The command line imports them inside its error handling.
_LAZY = {"InputSpace": "uqflow.inputs", "RandomInput": "uqflow.inputs",
         "PropagationMethod": "uqflow.methods", "get_method": "uqflow.methods",
         "register_method": "uqflow.methods", "Solver": "uqflow.solver",
         "get_solver": "uqflow.solver", "register_solver": "uqflow.solver",
         "open_result": "uqflow.store", "sample_mask": "uqflow.methods",
         "solver_from_function": "uqflow.function_solver"}


def __getattr__(name):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'uqflow' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


def load_study(path, overrides=None):
    """Read and validate a study file, with ``overrides`` ({dotted key: value}, as
    ``uqflow run --set`` gives them) set before validation (see ``uqflow.study.load_study``)."""
    from uqflow.study import load_study as _load
    return _load(path, overrides=overrides)


def run_study(study, **kwargs):
    """Run a loaded study (see ``uqflow.execute.run_study``)."""
    from uqflow.execute import run_study as _run
    return _run(study, **kwargs)


__all__ = ["AccuracyWarning", "InputSpace", "PropagationMethod", "RandomInput", "SceneError",
           "Solver", "SolverError", "StudyError", "get_method", "get_solver", "load_study",
           "open_result", "register_method", "register_solver", "run_study", "sample_mask",
           "solver_from_function",
           "__version__"]
