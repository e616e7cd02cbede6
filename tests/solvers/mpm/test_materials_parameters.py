"""The materials' parameter spec tables (materials/parameters.py): every parameter of every
named material declares its default, SI units and meaning once, in its model's module; the
library, the solver's ``parameter_units`` and the sensitivities read them from there."""

from __future__ import annotations

import math

import pytest

from solvers.mpm import MPMSolver
from solvers.mpm.materials import johnson_cook, jwl, library, mie_gruneisen, water
from solvers.mpm.materials.parameters import ParameterSpec, units
from solvers.mpm.probe_sensitivities import JC_PARAMETERS, LOCAL_PARAMETERS, MG_PARAMETERS

# ``UNITS_BY_NAME`` as solver.py spelled it out before the spec tables (commit 0a5718c); every
# other parameter name got "" there
UNITS_BEFORE = {"rho0": "kg m-3", "shear_modulus": "Pa", "E": "Pa", "D": "m s-1",
                "eos.C": "m s-1", "eos.A": "Pa", "eos.B": "Pa", "eos.E0": "J m-3",
                "jc.A": "Pa", "jc.B": "Pa", "jc.eps0_dot": "s-1", "jc.T_room": "K",
                "jc.T_melt": "K", "cp": "J kg-1 K-1", "cavitation_pressure": "Pa",
                "burn_width": "m", "det_x": "m", "det_y": "m"}


@pytest.mark.parametrize("name", sorted(library.MATERIALS))
def test_every_library_parameter_has_default_units_and_meaning(name):
    module, defaults = library.MATERIALS[name]
    specs = module.PARAMETER_SPECS
    assert all(isinstance(s, ParameterSpec) for s in specs)
    names = [s.name for s in specs]
    assert len(set(names)) == len(names)                       # one row per parameter
    assert list(module.PARAMETERS) == names                     # the packed vector's order
    assert module.NPRM == len(specs)
    for s in specs:
        assert isinstance(s.default, float) and math.isfinite(s.default), s
        assert isinstance(s.units, str), s                       # "" for a pure number
        assert s.meaning.strip(), s
    assert defaults is module.PARAMETERS                       # the library copies nothing
    assert module.pack().tolist() == [s.default for s in specs]


@pytest.mark.parametrize("module", [johnson_cook, water, jwl, library.MATERIALS["elastic"][0]])
def test_units_from_the_spec_tables_equal_the_former_solver_table(module):
    assert units(module.PARAMETER_SPECS) == {n: UNITS_BEFORE.get(n, "")
                                             for n in module.PARAMETERS}


def test_both_mie_gruneisen_materials_share_the_eos_rows():
    eos = [s.name for s in mie_gruneisen.eos_parameters(1, 2, 3, 4, 5, 6)]
    for module in (johnson_cook, water):
        rows = module.PARAMETER_SPECS[:len(eos)]
        assert [s.name for s in rows] == eos
        assert [s.units for s in rows] == [s.units for s in mie_gruneisen.eos_parameters(
            *(s.default for s in rows))]


def test_differentiable_parameters_come_from_the_models():
    assert JC_PARAMETERS is johnson_cook.DIFFERENTIABLE_PARAMETERS
    assert MG_PARAMETERS is mie_gruneisen.DIFFERENTIABLE_PARAMETERS
    assert LOCAL_PARAMETERS == MG_PARAMETERS + JC_PARAMETERS
    assert set(LOCAL_PARAMETERS) <= set(johnson_cook.PARAMETERS)


def test_solver_parameter_units_come_from_the_materials():
    scene = dict(domain=dict(x=[0.0, 0.1], y=[0.0, 0.1]), cell_size=0.01,
                 particles_per_cell=2,
                 materials=dict(steel=dict(model="steel_4340"), sea=dict(model="water"),
                                hx=dict(model="tnt"), bar=dict(model="elastic")),
                 bodies=[dict(name="plate", material="steel", shape="rectangle",
                              min=[0.04, 0.0], max=[0.06, 0.1]),
                         dict(name="charge", material="hx", shape="rectangle",
                              min=[0.0, 0.0], max=[0.02, 0.1]),
                         dict(name="rod", material="bar", shape="rectangle",
                              min=[0.08, 0.0], max=[0.1, 0.1]),
                         dict(name="sea", material="sea", shape="rectangle",
                              min=[0.0, 0.0], max=[0.1, 0.1])],
                 detonation=dict(point=[0.0, 0.05]), end_time=1e-6, output_interval=1e-6,
                 probes=[dict(name="c", point=[0.05, 0.05], body="plate")])
    solver = MPMSolver.from_scene(scene)
    got = solver.parameter_units()
    assert set(got) == set(solver.nominal())
    assert {k.split(".", 1)[0] for k in got} == {"steel", "sea", "hx", "bar"}
    assert got == {k: UNITS_BEFORE.get(k.split(".", 1)[1], "") for k in got}
