"""From a design to a sensor a fab lab can make (paper appendices B and C).

``route`` (:mod:`mscap.fabrication.router`) joins the plates of each row and column of
the multiplexed array to a connector edge under the scene's ``[fabrication]`` rules;
:mod:`mscap.fabrication.stencil` writes one stencil per conductive layer (DXF, SVG), a
preview and ``fabrication.json``; :mod:`mscap.fabrication.check` checks the design rules
on the files as written.

Its public names load their module on first use::

    from mscap.fabrication import route, write_fabrication
    routing = route(layout.outlines, scene.sheet_outline_mm, scene.fabrication)
    write_fabrication(routing, "out/stencils", scene, "my design")   # preview=plot_routing draws preview.png
"""

from mscap._lazy import lazy_names

__all__, __getattr__ = lazy_names(__name__, {
    "route": "router",
    "Routing": "router",
    "write_fabrication": "report",
    "wiring_of": "wired",
    "plates_only": "wired",
    "readings": "wired",
    "read_wiring_dir": "wired",
    "wiring_offset": "during",
})
