"""Virtual calibration: fit pose reconstruction on simulated read-outs, report the error.

Its public names load their module on first use::

    from mscap.calibration import Candidate, evaluate, simulate_family
    # the pose family of each design simulated once (cached), then scored under noise
"""

from mscap._lazy import lazy_names

__all__, __getattr__ = lazy_names(__name__, {
    "simulate_family": "service",
    "evaluate": "service",
    "Candidate": "service",
    "fit": "reconstruction",
    "score": "reconstruction",
})
