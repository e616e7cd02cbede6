"""The numbers README.md states that are not benchmark figures, asserted where they come from.

Timings in the README ("a few seconds", "about 30 s per run") are benchmark figures with their
commands in BENCHMARKS.md; everything else it states is checked here or by the test it names.
"""

import math
import re
import tomllib
from pathlib import Path

import pytest

from uqflow.study import ExecutionSpec, load_study

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()
STUDIES = ROOT / "studies"


def _stated(pattern: str) -> re.Match:
    found = re.search(pattern, README, flags=re.S)
    assert found, f"README.md no longer says /{pattern}/: update this test with the text"
    return found


def test_ishigami_exact_moments_as_stated():
    # Ishigami with a = 7, b = 0.1 on U(-pi, pi)^3: E = a/2, Var = a^2/8 + b pi^4/5
    # + b^2 pi^8/18 + 1/2 (Sobol' & Levitan 1999); the README rounds to 4 decimals.
    a, b = 7.0, 0.1
    variance = a**2 / 8 + b * math.pi**4 / 5 + b**2 * math.pi**8 / 18 + 0.5
    stated = _stated(r"mean ([0-9.]+) and variance\s+([0-9.]+)")
    assert float(stated.group(1)) == a / 2
    assert float(stated.group(2)) == pytest.approx(variance, abs=5e-5)  # 4 decimals shown


def test_ishigami_study_is_what_the_readme_describes():
    study = load_study(STUDIES / "ishigami_mc.toml")
    options = study.method.options
    points = int(_stated(r"ishigami_mc.toml`:\s+(\d+) scrambled Sobol").group(1))
    assert (options.samples, options.rule, options.replicates) == (points, "sobol", 8)


def test_quickstart_is_what_the_readme_describes():
    study = load_study(STUDIES / "quickstart.toml")
    options = study.method.options
    samples = int(_stated(r"and (\d+) Monte Carlo runs that use").group(1))
    runs = int(_stated(r"(\d+) runs of an [0-9,]+-particle scene").group(1))
    particles = int(_stated(r"runs of an ([0-9,]+)-particle scene").group(1).replace(",", ""))
    replicates, per = map(int, _stated(r"\((\d+) independently scrambled Sobol' replicates "
                                       r"of (\d+), Student t").groups())
    dof = int(_stated(r"replicates of \d+, Student t with (\d+) degrees of freedom").group(1))
    cv = float(_stated(r"Johnson.Cook parameters normal with C.V. ([0-9.]+)").group(1))
    assert (options.samples, options.rule, options.control) == (samples, "sobol", "taylor-local")
    assert (options.replicates, replicates * per, dof) == (replicates, samples, replicates - 1)
    assert runs == samples + 1                       # the control run, then the samples
    assert study.solver.parts.x.size == particles
    assert len(study.space.inputs) == 5
    assert all(i.name.startswith("steel.jc.") and i.kind == "normal" for i in study.space.inputs)
    # the study's literal 0.10 against the README's: one rounding each
    assert [i.cv for i in study.space.inputs] == pytest.approx([cv] * 5, rel=1e-15)
    assert study.spec.execution.workers == 0      # README: in-process, one compile


def test_execution_defaults_as_stated():
    defaults = ExecutionSpec()
    interval = float(_stated(r"checkpoint_interval` \(default (\d+) s\)").group(1))
    fraction = float(_stated(r"max_failure_fraction` \(default ([0-9.]+)\)").group(1))
    assert defaults.checkpoint_interval == interval
    assert defaults.max_failure_fraction == fraction


def test_adaptive_study_target_as_stated():
    percent = float(_stated(r"adaptive Monte Carlo that stops at ([0-9.]+) % standard").group(1))
    study = tomllib.loads((STUDIES / "mc_random_E_bar.toml").read_text())
    # percent / 100 rounds once: within eps (2.2e-16) of the study's decimal literal
    assert study["method"]["target_rel_stderr"] == pytest.approx(percent / 100, rel=1e-15)


@pytest.mark.parametrize("scene, pattern", [
    ("mpm_contact_thin_small.toml", r"cropped scenes \(([0-9,]+) particles"),
    ("mpm_contact_thin.toml", r"seed's size \(`\*_seed_size.toml`, ([0-9,]+) particles"),
])
def test_mpm_particle_counts_as_stated(scene, pattern):
    from solvers.mpm import MPMSolver

    stated = int(_stated(pattern).group(1).replace(",", ""))
    solver = MPMSolver.from_scene(tomllib.loads((STUDIES / "scenes" / scene).read_text()))
    assert solver.parts.x.size == stated


def test_sph_scenes_as_stated():
    """The SPH example scenes the README names are the sph_*.toml files in studies/scenes."""
    sentence = _stated(r"The corrected SPH of seed 001 has (.*?)\s+and, in `studies/sph/`").group(1)
    named = set(re.findall(r"studies/scenes/(sph_\w+\.toml)", sentence))
    assert named == {p.name for p in (STUDIES / "scenes").glob("sph_*.toml")}
    numbers = sorted(int(n) for n in re.findall(r"sph_example(\d+)\.toml", " ".join(named)))
    listed = ", ".join(map(str, numbers[:-1])) + " and " if len(numbers) > 1 else ""
    assert f"examples {listed}{numbers[-1]} " in " ".join(sentence.split()), sentence


def test_result_file_versions_as_stated():
    """The packages whose versions the README says a result records are those it records."""
    from uqflow.store import versions
    listed = _stated(r"versions of (.*?),\s+`complete`").group(1)
    names = {n.strip() for n in re.split(r",|\band\b", " ".join(listed.split())) if n.strip()}
    assert names == {key.removeprefix("version_") for key in versions()}
