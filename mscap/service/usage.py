"""What a start costs its worker, measured by the worker itself: CPU seconds (user +
system, every thread of the process: core-seconds) and peak resident memory.

Stored with each run (``cpu_s``, ``error_estimate_cpu_s``, ``peak_rss_mb``), they survive
whatever ends the job: a ``/usr/bin/time -v`` around a rank dies with it on SIGTERM, and
one around ``mpirun`` measures ``mpirun`` (docs/performance.md §10). ``mscap inspect``
sums them into the job's core-hours and names its largest worker.

The peak is the process's high-water mark (``VmHWM``), reset when a start begins by
writing ``5`` to ``/proc/self/clear_refs`` (Linux ≥ 4.0), so it is that start's own. Where
the reset is refused (another kernel, a locked-down ``/proc``) it is the worker's peak so
far, an upper bound, from ``getrusage``.
"""

from __future__ import annotations

import resource
import sys
import time

__all__ = ["Meter", "peak_rss_mb", "reset_peak"]


def reset_peak() -> bool:
    """Reset this process's peak resident memory to its current size; False if refused."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def peak_rss_mb() -> float:
    """This process's peak resident memory since :func:`reset_peak` (or since it started), MB."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024  # kB
    except (OSError, ValueError, IndexError):
        pass
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # kB on Linux, bytes on macOS
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024


class Meter:
    """CPU time and peak memory from its creation on (creating one resets the peak)."""

    def __init__(self) -> None:
        reset_peak()
        self._cpu0 = time.process_time()

    @property
    def cpu_s(self) -> float:
        """CPU seconds of every thread of this process since the meter started."""
        return time.process_time() - self._cpu0

    @property
    def peak_rss_mb(self) -> float:
        return peak_rss_mb()
