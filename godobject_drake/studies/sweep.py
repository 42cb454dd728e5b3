"""Run many independent simulations: local processes by default, a Dask cluster on request.

The speed-vs-error benchmark (``analysis/speed_vs_error.py``) hands its cases to
:func:`run_tasks`::

    results = run_tasks(simulate_one, cases, workers=2)                  # this machine
    results = run_tasks(simulate_one, cases, scheduler="tcp://host:8786")  # a Dask cluster

``fn`` must be importable by the workers (a module-level function of an
installed package: ``godobject_drake`` itself, as ``pip install -e .``
makes it), and the cases picklable. Results come back in the order of the
cases, whatever order they finish in; a progress bar counts them.

Timing: cases that measure wall time should not share a core. On this
2-core machine the default is one worker; a cluster runs each case in
whatever process the scheduler picks, so compare timings within one
worker type.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import sys
from collections.abc import Callable, Sequence


def _bar(total: int, desc: str, enabled: bool):
    from tqdm import tqdm

    return tqdm(
        total=total, desc=desc, unit="run", file=sys.stderr, disable=None if enabled else True, leave=False
    )


def run_tasks(
    fn: Callable,
    cases: Sequence,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    progress: bool = True,
    desc: str = "sweep",
) -> list:
    """``[fn(case) for case in cases]``, run by an executor.

    Parameters
    ----------
    fn : callable
        ``fn(case) -> result``; importable by the workers.
    cases : sequence
        Picklable arguments, one per run.
    workers : int
        Local worker processes (``scheduler`` None). 0 runs in this process (no pickling,
        for debugging and for tests that need the caller's state).
    scheduler : str | None
        Address of a running Dask distributed scheduler (``tcp://host:8786``); needs the
        ``cluster`` extra (``pip install -e .[cluster]``).
    progress : bool
        Show a progress bar on stderr.

    Raises
    ------
    ValueError
        ``workers`` < 0, or both a scheduler and ``workers`` = 0.
    Exception
        The first exception a case raised, re-raised here with the case it came from.
    """
    cases = list(cases)
    if not isinstance(workers, int) or workers < 0:
        raise ValueError(f"workers={workers!r}; give an integer ≥ 0 (0 = run in this process)")
    if scheduler is not None and workers == 0:
        raise ValueError("workers=0 runs in this process; drop it to use the scheduler")
    bar = _bar(len(cases), desc, progress)
    try:
        if scheduler is not None:
            return _run_dask(fn, cases, scheduler, bar)
        if workers == 0:
            out = []
            for case in cases:
                out.append(_call(fn, case))
                bar.update(1)
            return out
        # "spawn": a fresh interpreter per worker. Forking a process that has loaded Drake
        # (which may have started threads, e.g. a Meshcat server) is not safe.
        ctx = multiprocessing.get_context("spawn")
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            futures = {pool.submit(_call, fn, case): i for i, case in enumerate(cases)}
            out = [None] * len(cases)
            for future in cf.as_completed(futures):
                out[futures[future]] = future.result()
                bar.update(1)
            return out
    finally:
        bar.close()


def _call(fn, case):
    try:
        return fn(case)
    except Exception as e:
        raise RuntimeError(f"{getattr(fn, '__name__', fn)}({case!r}) failed: {e}") from e


def _run_dask(fn, cases, scheduler: str, bar) -> list:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ImportError(
            "--scheduler needs Dask distributed; install the extra: pip install -e .[cluster]"
        ) from None
    with Client(scheduler, timeout="30s") as client:
        futures = client.map(_call, [fn] * len(cases), cases, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        out = [None] * len(cases)
        for future in as_completed(futures):
            out[index[future.key]] = future.result()
            bar.update(1)
        return out
