"""Measurements a run reports about itself: its peak resident memory (parefg.profiling)."""

import subprocess
import sys

import numpy as np
import pytest

from parefg.profiling import peak_rss_kib

CHILD = "from parefg.profiling import peak_rss_kib; print(peak_rss_kib())"


@pytest.mark.serial_only
def test_peak_rss_is_the_process_own_not_its_parents():
    """Linux carries a parent's peak into the child's ru_maxrss at exec: a run started from
    a large test worker reported ~955 MB for its ~580 MB.  The child must report its own."""
    held = np.ones(64 * 2**20)  # 512 MiB touched by this (parent) process
    parent = peak_rss_kib()
    assert parent > 512 * 1024
    child = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True)
    assert child.returncode == 0, child.stderr
    assert int(child.stdout) < parent - 256 * 1024, (int(child.stdout), parent)
    del held
