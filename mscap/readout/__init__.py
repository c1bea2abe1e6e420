"""Multiplexed read-out of the capacitor array: the array model and lead patterns.

Its public names load their module on first use::

    from mscap.readout import grid_array
    array = grid_array(5)                        # 5 capacitors in a 3 x 2 array
"""

from mscap._lazy import lazy_names

__all__, __getattr__ = lazy_names(__name__, {
    "CapacitorArray": "array",
    "grid_array": "array",
    "read_wiring": "array",
    "optimise_patterns": "patterns",
    "default_patterns": "patterns",
})
