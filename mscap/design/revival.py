"""Reviving a plate that reads nothing (issue 45 item 3).

A start's plate can sit where no design pose strains the sheet: a Lloyd start on the
glove puts two of its four plates on the back of the hand, 27 mm from the knuckles, where
every pose reads the same to 1e-4. Such a plate adds nothing to the objective and gets no
gradient: the optimiser never moves it (the glove's k = 4 Lloyd starts ended at 0.177 and
0.230 mm calibrated against the hand-placed layout's 0.140).

**Silent.** Plate j is silent when leaving its column out of the design poses'
capacitances changes the objective's capacitance term (the bound, the dissimilarity) by
less than :data:`SILENT_SHARE` of it: it tells the optimiser nothing the others do not.

**Where to.** The sensitivity map of the design poses (:mod:`mscap.design.starts`) gives
every triangle of the sheet its signature, the log capacitance density a small plate
there would read across the poses. What the plates that do read already say is the span
of their own log-capacitance signals over the same poses (centred over the poses: a tare
or a common factor says nothing). A triangle's **novelty** is the part of its signature
outside that span; a square plate of the silent plate's area centred at a point reads
about the mean signature of the triangles it covers, and its novelty is that mean's part
outside the span. The silent plate moves, as a square, to the point of greatest novelty
where it fits (the scene's gap from the other plates and the sheet edge, shrunk by 10 %
at most :data:`SIZES` times); a second silent plate then counts the first one's predicted
signal as read.

**Kept only if it pays.** The optimiser meshes the moved layout, simulates it (each
pose warm-started from the current equilibria, as at a remesh) and keeps it only if J
falls; the start's own layout stays its baseline (``initial``). It tries at the start and
when a level converges (not when it runs out of iterations), once each.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from mscap.errors import GeometryError
from mscap.geometry import polygons as geometry
from mscap.geometry.initial import square_fits

__all__ = ["SILENT_SHARE", "SIZES", "Revival", "silent_plates", "novelty", "footprint_means", "revived_outlines",
           "revival"]

log = logging.getLogger(__name__)

#: A plate whose column changes the capacitance term by less than this share of it is silent
#: (the glove's two plates on the back of the hand: 2e-9 and 5e-9; its knuckle plates 0.18).
SILENT_SHARE = 0.01
#: A site is worth moving to when its novelty is at least this share of the map's strongest
#: signature (centred): the glove's back of the hand has 0.009 against 0.53 on a knuckle.
MIN_NOVELTY = 0.1
#: Square sizes tried at a site, 10 % apart (0.9⁷ ≈ half the silent plate's side).
SIZES = 8


@dataclass(frozen=True)
class Revival:
    """The silent plates ``plates``, their new outlines ``outlines`` (squares) and the
    novelty of each site (the norm of the predicted signal's part the other plates do not
    read, log-capacitance units over the design poses)."""

    plates: tuple[int, ...]
    outlines: tuple[np.ndarray, ...]
    novelty: tuple[float, ...]


def silent_plates(term, capacitance_pF: np.ndarray, share: float = SILENT_SHARE) -> tuple[int, ...]:
    """The plates (columns of ``capacitance_pF`` ``(n_poses, k)``) whose removal changes
    ``term``'s value (a capacitance term, :mod:`mscap.design.readback` or
    :class:`~mscap.design.objective.Dissimilarity`) by less than ``share`` of it."""
    c = np.asarray(capacitance_pF, dtype=float)
    if c.shape[1] < 2:
        return ()
    full = term.value(c)
    return tuple(j for j in range(c.shape[1])
                 if abs(term.value(np.delete(c, j, axis=1)) - full) <= share * abs(full))


def _centred(x: np.ndarray) -> np.ndarray:
    return x - x.mean(axis=-1, keepdims=True)


def novelty(signatures: np.ndarray, reading: np.ndarray) -> np.ndarray:
    """``(m, n)`` the part of each row of ``signatures`` (centred over the n poses) outside
    the span of the columns of ``reading`` ``(n, r)`` (centred too)."""
    t = _centred(np.asarray(signatures, dtype=float))
    if reading.shape[1] == 0:
        return t
    basis, s, _ = np.linalg.svd(_centred(reading.T).T, full_matrices=False)
    basis = basis[:, s > 1e-12 * max(s.max(), 1e-300)]
    return t - (t @ basis) @ basis.T


def footprint_means(points: np.ndarray, weight: np.ndarray, values: np.ndarray, size: float,
                    centres: np.ndarray | None = None, chunk: int = 256) -> np.ndarray:
    """``(c, n)`` the ``weight``-weighted mean of the rows of ``values`` ``(m, n)`` over the
    ``points`` ``(m, 2)`` inside an axis-aligned square of side ``size`` centred at each of
    ``centres`` (default: the points themselves); zero where a square covers none."""
    centres = points if centres is None else np.atleast_2d(centres)
    out = np.empty((len(centres), values.shape[1]))
    for a in range(0, len(centres), chunk):
        inside = (np.abs(points[None, :, :] - centres[a:a + chunk, None, :]) <= 0.5 * size).all(axis=2)
        w = inside * weight
        out[a:a + chunk] = w @ values / np.maximum(w.sum(axis=1), 1e-300)[:, None]
    return out


def revived_outlines(smap, outlines, capacitance_pF: np.ndarray, rows, silent, sheet: np.ndarray,
                     gap: float) -> Revival | None:
    """Squares for the ``silent`` plates of ``outlines`` at the points of greatest novelty
    of the sensitivity map ``smap`` where they fit (module docstring); ``rows``: the rows of
    ``capacitance_pF`` in the map's pose order. All silent plates shrink together, 10 % at a
    time, until each has a site (a plate left silent is wasted); if that never happens, the
    most plates that find one at the largest size move. ``None``: no plate has a site with
    :data:`MIN_NOVELTY` of the map's strongest signature."""
    outlines = [np.asarray(o, dtype=float) for o in outlines]
    signal = np.log(np.asarray(capacitance_pF, dtype=float)[rows])  # (n, k)
    reading = [signal[:, j] for j in range(len(outlines)) if j not in silent]
    sides = {j: float(np.sqrt(abs(geometry.signed_area(outlines[j])))) for j in silent}
    floor = MIN_NOVELTY * float(np.linalg.norm(_centred(smap.signature), axis=1).max())
    best, best_count = None, 0
    for step in range(SIZES):
        moved, scores, read = {}, {}, list(reading)
        for j in silent:
            size = sides[j] * 0.9**step
            residual = novelty(smap.signature, np.array(read).T.reshape(len(rows), -1))
            others = [moved.get(i, o) for i, o in enumerate(outlines) if i != j]
            site = _best_site(smap, residual, size, others, sheet, gap, floor)
            if site is not None:
                c, scores[j] = site
                moved[j] = geometry.square(smap.points[c], size)
                read.append(footprint_means(smap.points, smap.area, smap.signature, size, smap.points[c])[0])
        if len(moved) > best_count:
            best, best_count = (moved, scores), len(moved)
        if len(moved) == len(silent):
            break
    if best is None:
        log.info("revival: no site reads enough for plates %s", silent)
        return None
    moved, scores = best
    plates = tuple(j for j in silent if j in moved)
    return Revival(plates, tuple(moved[j] for j in plates), tuple(scores[j] for j in plates))


def _best_site(smap, residual: np.ndarray, size: float, others, sheet: np.ndarray, gap: float,
               floor: float) -> tuple[int, float] | None:
    """The map point where a square of side ``size`` adds the most novelty (the norm of the
    mean ``residual`` it covers) above ``floor`` and fits beside ``others``: its index and
    that novelty, or ``None``."""
    gain = np.linalg.norm(footprint_means(smap.points, smap.area, residual, size), axis=1)
    for c in np.argsort(-gain, kind="stable"):
        if not gain[c] > floor:
            return None
        if square_fits(geometry.square(smap.points[c], size), others, sheet, gap):
            return int(c), float(gain[c])
    return None


def revival(design, evaluation) -> tuple[Revival, list] | None:
    """Where ``design``'s silent plates at ``evaluation`` would read something, and the
    outlines of the whole layout with them moved there: ``(Revival, outlines)``, or
    ``None`` when no plate is silent (or none fits elsewhere)."""
    from mscap.design.starts import sensitivity_map

    c = evaluation.capacitance_pF
    silent = silent_plates(design.objective.capacitance, c)
    if not silent:
        return None
    try:
        smap = sensitivity_map(design.scene)
    except GeometryError as exc:  # every pose free: nothing reads anywhere
        log.info("revival: %s", exc)
        return None
    family = design.designed.family
    rows = family.rows if family is not None else np.arange(len(design.poses))
    outlines = list(design.deformer.outlines(evaluation.q))
    found = revived_outlines(smap, outlines, c, rows, silent, design.scene.sheet_outline_mm,
                             2.0 * design.scene.min_gap_mm)
    if found is None:
        return None
    for j, square in zip(found.plates, found.outlines):
        outlines[j] = square
    return found, outlines
