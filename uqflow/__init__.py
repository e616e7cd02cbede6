"""uqflow: uncertainty propagation of material properties through particle solvers.

The Python API does everything the CLI does::

    import uqflow
    study = uqflow.load_study("studies/quickstart.toml")
    outcome = uqflow.run_study(study, workers=2)
    tree = uqflow.open_result(outcome.path)      # xarray.DataTree: runs, statistics
"""

from uqflow.errors import AccuracyWarning, SceneError, SolverError, StudyError
from uqflow.inputs import InputSpace, RandomInput
from uqflow.methods import PropagationMethod, get_method, register_method
from uqflow.solver import Solver, get_solver, register_solver
from uqflow.store import open_result

__version__ = "0.1.0"


def load_study(path):
    """Read and validate a study file (see ``uqflow.study.load_study``)."""
    from uqflow.study import load_study as _load
    return _load(path)


def run_study(study, **kwargs):
    """Run a loaded study (see ``uqflow.execute.run_study``)."""
    from uqflow.execute import run_study as _run
    return _run(study, **kwargs)


__all__ = ["AccuracyWarning", "InputSpace", "PropagationMethod", "RandomInput", "SceneError",
           "Solver", "SolverError", "StudyError", "get_method", "get_solver", "load_study",
           "open_result", "register_method", "register_solver", "run_study", "__version__"]
