"""Executors (slicer.scale.executors): one concurrent.futures path for serial, threads,
processes and Dask; outputs compared byte for byte with the in-process run."""
from __future__ import annotations

import concurrent.futures as cf
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from slicer import GridError, OptionError
from slicer.cli.app import main
from slicer.scale.executors import SerialExecutor, executor_info, map_ordered, open_executor
from slicer.job.run import run_slice
from slicer.scene.lattice import generate_lattice

distributed = pytest.importorskip("distributed", reason="Dask is in the 'dist' and 'test' extras")


@pytest.fixture(scope="module")
def cluster():
    """A 2-worker local Dask cluster for the whole module (in-process workers: fast)."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as c:
        yield c


@pytest.fixture(scope="module")
def lattice():
    return generate_lattice("bcc", cells=(3, 2, 2), cell_size=2.0, radius=0.15, radius_top=0.3)


@pytest.fixture(scope="module")
def scene(lattice, tmp_path_factory):
    p = tmp_path_factory.mktemp("scene") / "lattice.json"
    lattice.save(p)
    return p


def files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def serial_stack(lattice, tmp_path_factory):
    """The in-process reference: today's path (no plan)."""
    out = tmp_path_factory.mktemp("ref") / "stack"
    run_slice(lattice, out, pixel_size=0.05, progress=False)
    return files(out)


# ----------------------------------------------------------------------------- the interface
def test_serial_executor_runs_at_submit_and_keeps_exceptions_in_the_future():
    seen = []
    with SerialExecutor() as ex:
        f = ex.submit(seen.append, 1)
        assert seen == [1] and f.done() and f.result() is None
        g = ex.submit(lambda: 1 / 0)
        assert g.done()
        with pytest.raises(ZeroDivisionError):
            g.result()


class _Counting(cf.ThreadPoolExecutor):
    def __init__(self):
        super().__init__(max_workers=4)
        self.pending = 0
        self.most = 0
        self.lock = threading.Lock()

    def submit(self, fn, *args):
        with self.lock:
            self.pending += 1
            self.most = max(self.most, self.pending)

        def run():
            try:
                return fn(*args)
            finally:
                with self.lock:
                    self.pending -= 1
        return super().submit(run)


def test_map_ordered_keeps_input_order_and_bounds_the_window():
    def slow_first(i):
        time.sleep(0.05 if i % 3 == 0 else 0.0)
        return i * i

    with _Counting() as ex:
        args = [(i,) if i % 4 else None for i in range(20)]
        out = list(map_ordered(ex, slow_first, args, window=3))
    assert out == [None if i % 4 == 0 else i * i for i in range(20)]
    assert ex.most <= 3


def test_map_ordered_reraises_task_errors_in_order():
    def f(i):
        if i == 2:
            raise ValueError("tile 2")
        return i

    it = map_ordered(SerialExecutor(), f, [(i,) for i in range(5)], window=2)
    assert next(it) == 0 and next(it) == 1
    with pytest.raises(ValueError, match="tile 2"):
        next(it)


@pytest.mark.parametrize("kind, workers, scheduler, match", [
    ("mpi", None, None, "unknown executor 'mpi'"),
    ("threads", 0, None, "workers must be >= 1"),
    ("processes", None, "tcp://127.0.0.1:1", "--scheduler needs --executor dask"),
])
def test_open_executor_refuses_bad_requests(kind, workers, scheduler, match):
    with pytest.raises(OptionError, match=match):
        with open_executor(kind, workers, scheduler):
            pass


def test_unreachable_scheduler_is_a_clear_error(monkeypatch):
    import slicer.scale.executors

    monkeypatch.setattr(slicer.scale.executors, "CONNECT_TIMEOUT", "2s")
    t0 = time.perf_counter()
    with pytest.raises(OptionError, match="--scheduler: cannot reach the Dask scheduler at tcp://127.0.0.1:9"):
        with open_executor("dask", scheduler="tcp://127.0.0.1:9"):
            pass
    assert time.perf_counter() - t0 < 30


def test_executor_info_without_opening():
    assert executor_info("serial").task_threads is None
    info = executor_info("dask", scheduler="tcp://h:8786")
    assert (info.kind, info.workers, info.task_threads, info.address) == ("dask", 1, 1, "tcp://h:8786")
    assert "2 workers" in executor_info("processes", 2).describe()


# ----------------------------------------------------------------------------- byte-identical outputs
@pytest.mark.parametrize("kind", ["serial", "threads", "processes", "dask"])
def test_every_executor_writes_the_same_bytes(kind, lattice, serial_stack, cluster, tmp_path):
    """Tiles of 32 px and forced Z slabs (a streamed, two-pass job) on each
    executor: the PNG stack is byte-identical to the untiled in-process run."""
    scheduler = cluster.scheduler_address if kind == "dask" else None
    out = tmp_path / "stack"
    with open_executor(kind, 2, scheduler) as (ex, info):
        from slicer.scale.tiles import plan_slice

        K = plan_slice(lattice, 0.05, process_bytes=0).grid.layers
        budget = plan_slice(lattice, 0.05, executor_info=info, tile=32, sample=True,
                            slab=-(-K // 3), prefetch=False).estimate["total"]
        summary = run_slice(lattice, out, pixel_size=0.05, progress=False, max_memory=budget, executor=ex,
                            executor_info=info, tile=32)
    plan = summary["plan"]
    assert plan["tiles"] > 4 and plan["slabs"] >= 3 and plan["passes"] == 2
    if kind != "serial":
        assert summary["threads"] == 1          # workers run single-threaded kernels
    assert files(out) == serial_stack


def test_threads_1_and_2_write_the_same_bytes(lattice, serial_stack, tmp_path):
    for n in (1, 2):
        out = tmp_path / f"t{n}"
        run_slice(lattice, out, pixel_size=0.05, progress=False, threads=n, tile=64, max_memory=None,
                  executor=SerialExecutor(), executor_info=executor_info("serial"))
        assert files(out) == serial_stack


def test_cli_dask_scheduler_output_matches_local_run(scene, cluster, tmp_path):
    """Through the real CLI: --executor dask --scheduler ADDRESS vs the default run."""
    local, remote = tmp_path / "local", tmp_path / "dask"
    r = CliRunner().invoke(main, ["slice", str(scene), "-o", str(local), "--pixel-size", "0.05", "-q"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["slice", str(scene), "-o", str(remote), "--pixel-size", "0.05", "-q",
                                  "--executor", "dask", "--scheduler", cluster.scheduler_address,
                                  "--tile", "64", "--max-memory", "none"])
    assert r.exit_code == 0, r.output
    assert files(local) == files(remote)
    assert len(files(local)) > 10


def test_pool_workers_get_numpy_arrays_not_the_scene(lattice):
    """The task payload is the culled arrays (small), picklable for any pool."""
    import pickle

    from slicer.model.field import support_boxes
    from slicer.tracer.grid import make_grid
    from slicer.scale.tiles import TraceOptions, cull, trace_tile

    g = make_grid(lattice.support_bounds(), 0.05)
    sub = g.sub(0, 0, 0, 32, 32, g.layers)
    args = (*cull(lattice, *support_boxes(lattice), sub), lattice.degree, lattice.sigma, sub, TraceOptions(threads=1))
    assert all(isinstance(a, np.ndarray) for a in args[:3]) and len(args[1]) < lattice.n_segments
    payload = pickle.dumps((trace_tile, args))
    assert len(payload) < 20_000


_CACHED_KERNEL = '''
import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True)
def total(a):
    s = 0.0
    for i in prange(a.size):
        s += a[i]
    return s


def task(_):
    total(np.ones(100))            # loaded from the cache: the worker's threads start, no compile
    fresh = njit(lambda x: x + 1)  # a later compile reloads Numba's configuration
    return total(np.ones(100)) + fresh(1)
'''


def test_process_workers_may_compile_after_their_threads_started(tmp_path, monkeypatch):
    """A process worker whose kernels come from Numba's cache starts its threads
    without compiling; a compile after that reloads Numba's configuration. The
    worker's thread limit must already be in it then, or Numba refuses to go on
    ("Cannot set NUMBA_NUM_THREADS ... once the threads have been launched")."""
    import numba

    if numba.config.NUMBA_DEFAULT_NUM_THREADS < 2:
        pytest.skip("one core: a worker's default thread count is already its limit")
    (tmp_path / "cached_kernel_mod.py").write_text(_CACHED_KERNEL)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delenv("NUMBA_NUM_THREADS", raising=False)
    import cached_kernel_mod

    cached_kernel_mod.total(np.ones(10))            # fills the cache for the workers
    with open_executor("processes", 1) as (ex, _):
        assert list(ex.map(cached_kernel_mod.task, [0, 1])) == [102.0, 102.0]
