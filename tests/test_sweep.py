"""The sweep runner: same results in this process, in local worker processes and on a Dask
cluster started here (issue 6: "tested against a local Dask cluster started by the test")."""

import math

import numpy as np
import pytest

from godobject_drake.config.scenario import replace, shipped_scenario
from godobject_drake.limits import explicit_limit_omega_h
from godobject_drake.studies.benchmark import make_case, run_case
from godobject_drake.studies.sweep import run_tasks

ZETAS = [0.0, 0.5, 0.7, 1.0, 2.0]


def test_local_processes_return_results_in_case_order():
    expected = [2 * (math.sqrt(1 + z * z) - z) for z in ZETAS]  # docs/theory.md §1, by hand
    assert run_tasks(explicit_limit_omega_h, ZETAS, workers=0, progress=False) == expected
    assert run_tasks(explicit_limit_omega_h, ZETAS, workers=2, progress=False) == expected


def test_a_failing_case_is_named():
    with pytest.raises(RuntimeError, match=r"explicit_limit_omega_h\('x'\) failed"):
        run_tasks(explicit_limit_omega_h, [1.0, "x"], workers=0, progress=False)


def test_bad_worker_count_is_refused():
    with pytest.raises(ValueError, match=r"workers=-1.*≥ 0"):
        run_tasks(explicit_limit_omega_h, ZETAS, workers=-1)


@pytest.mark.slow
def test_dask_cluster_runs_the_same_drake_simulations():
    """Two brick-scene runs on a local Dask cluster give the trajectories this process gets:
    the simulation is deterministic, so the scheduler must not change a number."""
    distributed = pytest.importorskip("distributed")
    lego = shipped_scenario("lego")
    cases = [
        make_case(replace(lego, **{"plant.time_step": h, "simulation.duration_s": 0.3}), repeats=1)
        for h in (2e-3, 5e-3)
    ]
    here = run_tasks(run_case, cases, workers=0, progress=False)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        there = run_tasks(run_case, cases, scheduler=cluster.scheduler_address, progress=False)
    for a, b in zip(here, there, strict=True):
        assert a["label"] == b["label"]
        np.testing.assert_array_equal(a["p_WG"], b["p_WG"])
        np.testing.assert_array_equal(a["energy_j"], b["energy_j"])
    assert here[0]["p_WG"][-1, 2] > 0.01  # brick_0 is being lifted (the path's first 0.5 s)
