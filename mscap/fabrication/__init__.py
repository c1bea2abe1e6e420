"""From a design to a sensor a fab lab can make (paper appendices B and C).

``route`` (:mod:`mscap.fabrication.router`) joins the plates of each row and column of
the multiplexed array to a connector edge under the scene's ``[fabrication]`` rules;
:mod:`mscap.fabrication.stencil` writes one stencil per conductive layer (DXF, SVG), a
preview and ``fabrication.json``; :mod:`mscap.fabrication.check` checks the design rules
on the files as written.
"""
