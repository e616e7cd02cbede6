"""`uqflow report` on sph results (solvers/sph/report.py)."""

import numpy as np
import xarray as xr

from solvers.sph.report import detach_probability, report


def fake_tree(detached):
    detached = np.asarray(detached, float)
    r, s = detached.shape
    runs = xr.Dataset({
        "status": ("realization", np.array(["ok"] * r)),
        "effective_modulus": ("realization", np.linspace(1.3e6, 1.5e6, r)),
        "modulus_lower_bound": ("realization", np.full(r, 1.0e6)),
        "modulus_upper_bound": ("realization", np.full(r, 1.4e6)),
        "volume_fraction": ("realization", np.full(r, 0.1)),
        "strain": (("realization", "step"), np.tile(np.arange(1, s + 1) * 1e-3, (r, 1))),
        "macro_stress": (("realization", "step"), np.tile(np.arange(1, s + 1) * 1e3, (r, 1))),
        "detached_inclusions": (("realization", "step"), detached)})
    return xr.DataTree.from_dict({"/": xr.Dataset(attrs={"study_name": "t"}), "/runs": runs})


def test_detach_probability_and_its_binomial_error():
    tree = fake_tree([[0, 0, 1], [0, 1, 1], [0, 0, 0], [0, 0, 2]])
    p, se = detach_probability(tree["runs"].to_dataset())
    assert p.tolist() == [0.0, 0.25, 0.75]
    assert se[2] == np.sqrt(0.75 * 0.25 / 4)


def test_report_counts_moduli_within_bounds_and_draws(tmp_path):
    text, pngs = report([fake_tree(np.zeros((5, 3)))], tmp_path)
    assert "within the Hashin-Shtrikman bounds of its volume fraction: 2 of 5" in text  # 1.3, 1.35 (1.4 is on it)
    assert "= 0.000 ± 0.000" in text
    assert len(pngs) == 1 and pngs[0].exists()
