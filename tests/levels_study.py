"""The small study the levels tests share: the analytic Euler decay model, one uniform input,
its step count as the levels' key; each test varies only what it is about."""

from __future__ import annotations


def euler_levels_study(name: str, *, kind: str = "multilevel", solver: str = "analytic",
                       scene_extra: str = "", outputs: str = '["y"]', key: str = "steps",
                       values: str = "[4, 8, 16]", align: str | None = None,
                       target_rmse: float = 0.02,
                       method_extra: str = "costs = [1.0, 2.0, 4.0]",
                       output: str | None = None, seed: int = 5) -> str:
    """The study's TOML text (values and outputs as TOML text); with ``output``, in-process
    execution (workers = 0, ``seed``) writing that result file without figures."""
    align_line = "" if align is None else f'align = "{align}"\n'
    text = f"""\
name = "{name}"
solver = "{solver}"
scene = {{ model = "euler_decay"{scene_extra} }}
outputs = {outputs}

[[inputs]]
name = "k"
distribution = "uniform"
lower = 0.5
upper = 1.5

[levels]
key = "{key}"
values = {values}
{align_line}
[method]
kind = "{kind}"
target_rmse = {target_rmse}
pilot = 8
{method_extra}
"""
    if output is not None:
        text += (f"\n[execution]\nworkers = 0\nseed = {seed}\n\n"
                 f'[output]\npath = "{output}"\nfigures = false\n')
    return text
