"""Figures and field files for viewing: :mod:`~mscap.viz.layouts` (a results file's best
layout per k, and the layout drawing every figure shares), :mod:`~mscap.viz.optimize` (one
start, before and after), :mod:`~mscap.viz.calibration` (reconstruction error per pose),
:mod:`~mscap.viz.vtu` (solved fields as VTU files for ParaView).

matplotlib is imported inside the drawing functions (Agg backend), never on import.
"""
