"""Threads for an output-only identification's decompositions: the same model bit for bit, sooner.

``identify_output_only(workers=N)`` decomposes the stabilization diagram's orders and the
jackknife's replicates side by side (:mod:`okid_ros.core.worker_threads`). Each thread runs the
call the serial code makes on the same arrays, so every number must equal the one-thread run's
exactly: a difference means a task read state another one wrote.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from okid_bench.output_only_cases import output_only_case
from okid_ros.core.output_only import identify_output_only
from okid_ros.core.worker_threads import WorkerThreads


def _fingerprint(model) -> tuple:
    """Every number a user reads of the model, as bytes (exact comparison)."""
    modes = tuple((m.frequency_hz, m.damping_ratio, m.frequency_hz_std, m.damping_ratio_std, m.shape.tobytes(),
                   tuple(sorted(m.extras.items()))) for m in model.modes)
    return (model.A.tobytes(), model.C.tobytes(), model.K.tobytes(), model.innovation_covariance.tobytes(),
            modes, tuple(model.warnings), len(model.stabilization))


@pytest.mark.parametrize(("case", "method"), [("low-modes", "ssi-cov"), ("close-pair", "ssi-cov"),
                                              ("low-modes", "ssi-cva"), ("close-pair", "ssi-cva")])
def test_threads_give_the_one_thread_model_bit_for_bit(case: str, method: str) -> None:
    """low-modes also runs the decimated band's pass (its own diagram and jackknife) in the threads."""
    simulated = output_only_case(case)
    y = simulated.simulate(0)[:30000]
    serial = identify_output_only(y, simulated.sample_time_s, method=method)
    threaded = identify_output_only(y, simulated.sample_time_s, method=method, workers=3)
    assert serial.modes, "the record gave no mode: the comparison would hold nothing"
    if (case, method) == ("low-modes", "ssi-cov"):  # the decimated pass ran, so its threads were compared too
        assert any("decimation" in mode.extras for mode in serial.modes)
    assert _fingerprint(threaded) == _fingerprint(serial)


def test_the_work_runs_in_another_thread_beside_the_caller_and_it_is_joined() -> None:
    started = threading.Event()

    def waits_for_the_caller() -> str:  # returns only if the caller runs on meanwhile
        started.set()
        assert release.wait(10)
        return threading.current_thread().name

    release = threading.Event()
    with WorkerThreads(2) as threads:
        task = threads.submit(waits_for_the_caller)
        assert started.wait(10)
        release.set()
        assert task.result().startswith("okid_worker")
        assert threads.map(lambda k: k * k, range(40)) == [k * k for k in range(40)]
    assert not any(t.name.startswith("okid_worker") and t.is_alive() for t in threading.enumerate())


def test_the_caller_does_the_work_no_thread_has_begun() -> None:
    """Work queued behind a busy thread (the replicates, before the diagram) is done by the caller, not waited for."""
    caller, names = threading.current_thread().name, []
    busy, release = threading.Event(), threading.Event()

    def occupy() -> None:
        busy.set()
        assert release.wait(10)

    with WorkerThreads(2) as threads:
        occupying = threads.submit(occupy)
        assert busy.wait(10)
        queued = threads.submit(lambda: threading.current_thread().name)
        assert queued.result() == caller  # its thread is busy: run by the caller
        assert threads.map(lambda k: names.append(threading.current_thread().name) or k, range(5)) == list(range(5))
        assert set(names) == {caller}
        release.set()
        occupying.result()


def test_one_worker_runs_in_the_calling_thread_and_raises_at_once() -> None:
    names = []
    threads = WorkerThreads(1)
    assert threads.map(lambda k: names.append(threading.current_thread().name) or k, [1, 2]) == [1, 2]
    assert names == [threading.current_thread().name] * 2
    with pytest.raises(ZeroDivisionError):
        threads.submit(lambda: 1 / 0)


@pytest.mark.parametrize("where", ["submitted", "mapped"])
def test_an_error_in_a_thread_reaches_the_caller(where: str) -> None:
    bad = np.full((3, 3), np.nan)
    with WorkerThreads(2) as threads:
        with pytest.raises(np.linalg.LinAlgError):
            if where == "submitted":
                threads.submit(np.linalg.eig, bad).result()
            else:
                threads.map(np.linalg.eig, [np.eye(3), bad, np.eye(3), bad])
