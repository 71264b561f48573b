"""BLAS thread limits: applied around the library's calls and restored, also after threaded use."""

import os
import subprocess
import sys
import textwrap
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt import _threads
from factirl_opt.exceptions import ValidationError


def blas_counts():
    return [lib.num_threads for lib in _threads._blas_libraries()]


@pytest.fixture
def two_blas_threads():
    """Run under a limit of 2 BLAS threads (the test session runs under 1)."""
    with _threads.limit_blas_threads(2) as counts:
        yield counts


def test_limits_nest_and_restore(two_blas_threads):
    assert blas_counts() == two_blas_threads
    with _threads.limit_blas_threads(1) as inside:
        assert inside == blas_counts() == [1] * len(inside)
        with _threads.limit_blas_threads(2):
            assert blas_counts() == two_blas_threads
        assert blas_counts() == inside  # the outer limit is back
    assert blas_counts() == two_blas_threads
    with _threads.limit_blas_threads(0) as untouched:
        assert untouched == two_blas_threads


def test_limits_are_restored_after_threaded_use(two_blas_threads):
    grid = fo.GridWorld(5)
    R = np.random.default_rng(0).standard_normal((20, grid.n_states, 4))

    def work(i):
        with _threads.limit_blas_threads(1):
            fo.optimal_q(grid, R)
        return fo.optimal_q(grid, R)[0]

    with ThreadPoolExecutor(4) as pool:
        list(pool.map(work, range(16)))
    assert blas_counts() == two_blas_threads
    with _threads.limit_blas_threads(1), ThreadPoolExecutor(4) as pool:
        list(pool.map(work, range(16)))
    assert blas_counts() == two_blas_threads


def test_decorated_calls_limit_blas_in_the_main_thread_only(two_blas_threads, monkeypatch):
    seen = []

    @_threads.blas_limited
    def probe():
        seen.append(blas_counts())

    monkeypatch.setenv("FACTIRL_BLAS_THREADS", "1")
    probe()
    thread = threading.Thread(target=probe)
    thread.start()
    thread.join()
    assert seen == [[1] * len(two_blas_threads), two_blas_threads]
    assert blas_counts() == two_blas_threads


@pytest.mark.parametrize("raw", ["-1", "two"])
def test_bad_thread_setting(monkeypatch, raw):
    monkeypatch.setenv("FACTIRL_BLAS_THREADS", raw)
    with pytest.raises(ValidationError, match=f"FACTIRL_BLAS_THREADS must be a nonnegative integer; got '{raw}'"):
        _threads.blas_thread_limit()


def test_a_fresh_process_gets_its_blas_threads_back_after_threaded_use():
    """The counts before any limit opened come back when the last one closes (run in a fresh
    process: the test session itself runs under a limit)."""
    script = textwrap.dedent("""
        from concurrent.futures import ThreadPoolExecutor
        import numpy as np
        import factirl_opt as fo
        from factirl_opt import _threads
        before = [lib.num_threads for lib in _threads._blas_libraries()]
        grid = fo.GridWorld(5)
        R = np.random.default_rng(0).standard_normal((20, 25, 4))
        def work(i):
            with _threads.limit_blas_threads(1):
                return fo.optimal_q(grid, R)[0]
        with ThreadPoolExecutor(4) as pool:
            list(pool.map(work, range(16)))
        with ThreadPoolExecutor(4) as pool:
            list(pool.map(lambda i: fo.optimal_q(grid, R), range(50)))
        fo.optimal_q(grid, R)
        print(before == [lib.num_threads for lib in _threads._blas_libraries()], before)
    """)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="2")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("True"), out.stdout
