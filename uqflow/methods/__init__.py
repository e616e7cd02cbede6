"""Propagation methods: the registry, the contract and the built-in methods."""

from uqflow.methods.base import (MethodOptions, PropagationMethod, get_method, make_design,
                                 method_registry, register_method)
from uqflow.methods import monte_carlo as _monte_carlo  # noqa: F401  (registers built-ins)

try:  # built-ins still being written must not break the others
    from uqflow.methods import taylor as _taylor  # noqa: F401
except ImportError:  # pragma: no cover
    pass
try:
    from uqflow.methods import sobol as _sobol  # noqa: F401
except ImportError:  # pragma: no cover
    pass

__all__ = ["PropagationMethod", "MethodOptions", "register_method", "get_method",
           "method_registry", "make_design"]
