"""glibc allocator tuning (planning/allocator.py): what it leaves the process's allocator doing."""

import platform
import subprocess
import sys
import textwrap

import pytest

FAULTS = textwrap.dedent("""
    import resource
    import numpy as np
    from factirl_opt.planning.allocator import mapped_allocations

    with mapped_allocations():
        pass
    x = np.ones(2**18)
    del x
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(20):
        x = np.ones(2**18)  # 2 MiB from the heap (under the 32 MiB mmap threshold): 512 pages
        del x
    print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
""")


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc's allocator only")
def test_after_a_factorisation_freed_temporaries_stay_resident():
    # with glibc's trim threshold left at 128 KiB, every free returned the 2 MiB to the OS and every
    # new array faulted its 512 pages in again (9,600 faults over these 20 arrays)
    out = subprocess.run([sys.executable, "-c", FAULTS], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert int(out.stdout.strip().splitlines()[-1]) < 512
