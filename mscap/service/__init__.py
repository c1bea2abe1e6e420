"""The multi-start service: the MPI farm, starts, selection of k, the HDF5 store.

Its public names load their module on first use::

    from mscap.service import read_design, read_store
    with read_store("out/quick.h5") as store:
        design = read_design(store)              # the chosen run's outlines
"""

from mscap._lazy import lazy_names

__all__, __getattr__ = lazy_names(__name__, {
    "run_multistart": "multistart",
    "run_start": "multistart",
    "read_store": "store",
    "read_run": "store",
    "store_selection": "store",
    "read_design": "designs",
    "load_design": "designs",
})
