"""Propagation methods: the registry, the contract and the built-in methods."""

from uqflow.methods.base import (MethodOptions, PropagationMethod, finish_statistics,
                                 get_method, make_design, method_registry, ok_mask,
                                 output_names, register_method, sample_mask)
# Importing the built-ins registers them, also in a source tree that was never pip-installed.
from uqflow.methods import kl_weibull, monte_carlo, nominal, sobol, taylor  # noqa: E402,F401
from uqflow.methods import taylor_local  # noqa: E402,F401
from uqflow.methods import pce  # noqa: E402,F401
from uqflow.methods import multifidelity, multilevel  # noqa: E402,F401

__all__ = ["PropagationMethod", "MethodOptions", "register_method", "get_method",
           "method_registry", "make_design", "finish_statistics", "ok_mask", "output_names",
           "sample_mask"]
