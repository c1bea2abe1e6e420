"""Bodies the sheet is glued onto: the generator registry, one module per body, the glue model.

Its public names load their module on first use::

    from mscap.bodies import GENERATORS
    sorted(GENERATORS)                           # the object kinds a glue pose can name
"""

from mscap._lazy import lazy_names

__all__, __getattr__ = lazy_names(__name__, {
    "GENERATORS": "registry",
    "register_generator": "registry",
    "generator_parameters": "registry",
})
