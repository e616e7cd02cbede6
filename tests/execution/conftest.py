import textwrap

import pytest


ISHIGAMI_INPUTS = "".join(
    f"""
[[inputs]]
name = "x{i}"
distribution = "uniform"
lower = -3.141592653589793
upper = 3.141592653589793
""" for i in (1, 2, 3))


@pytest.fixture
def write_study(tmp_path):
    """Write a study file into tmp_path; returns its path. ``body`` is TOML after the header."""

    def write(name="s", scene='{ model = "ishigami" }', body=None, method=None,
              execution="workers = 0", inputs=ISHIGAMI_INPUTS, output=None, filename=None):
        method = method or 'kind = "monte-carlo"\nsamples = 256\nrule = "sobol"'
        output = output or f'path = "out/{name}.nc"\nfigures = false'
        text = textwrap.dedent(f"""\
            name = "{name}"
            solver = "analytic"
            scene = {scene}
            """) + inputs + (body or "") + f"\n[method]\n{method}\n\n[execution]\n{execution}\n" \
            f"\n[output]\n{output}\n"
        path = tmp_path / (filename or f"{name}.toml")
        path.write_text(text)
        return path

    return write
