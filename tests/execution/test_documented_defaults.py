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
