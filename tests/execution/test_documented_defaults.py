"""The execution defaults that docs/execution.md and the README state, as numbers."""

from types import SimpleNamespace

from uqflow import execute
from uqflow.study import ExecutionSpec


def test_the_stated_defaults():
    spec = ExecutionSpec()
    assert spec.checkpoint_interval == 2.0      # "checkpoint_interval (default 2 s)"
    assert spec.max_failure_fraction == 0.1     # "max_failure_fraction (default 0.1)"
    assert spec.workers == 2                    # "workers = N (default 2)"
    assert execute.CONNECT_TIMEOUT_S == 30.0    # "does not answer within 30 s"


def test_default_batches_are_eight_per_worker_and_at_most_128():
    study = SimpleNamespace(spec=SimpleNamespace(execution=ExecutionSpec()))
    assert execute._batch_size(study, 1600, 2) == 100
    assert execute._batch_size(study, 100_000, 2) == 128
    assert execute._batch_size(study, 10, 2) == 1


def test_monte_carlo_stop_points_start_at_min_samples_about_9_percent_apart():
    from uqflow.methods.monte_carlo import MonteCarlo

    points = MonteCarlo(samples=100_000, target_rel_stderr=0.01).stop_points(100_000)
    assert points[0] == 32 and points[-1] == 100_000          # min_samples (32) .. the plan
    ratios = (points[1:] / points[:-1])[:-1]   # the last step ends at the plan's size
    # 2^(1/8) = 1.0905 apart, each count rounded up: off by at most 1/count past 1000.
    assert ratios[points[:-2] >= 1000].max() < 1.0905 + 1 / 1000
    assert ratios[points[:-2] >= 1000].min() > 1.0905 - 1 / 1000
    assert MonteCarlo(samples=1000).stop_points(1000).size == 0  # no target: never asked
