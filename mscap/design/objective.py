"""Objective terms of the layout optimisation (paper §5), each with a value and a gradient.

The optimiser minimises

    J(C, X) = −d(C) + w_b B(X) + w_s S(X)

(+ w_b B_area(X) with ``max_plate_area_mm2``) with C the ``(n_poses, k)`` pose
capacitances (pF) and X the capacitor outlines (mm). :class:`LayoutObjective` is the one
place J is composed (:func:`layout_objective` builds it from a scene); its capacitance
and geometry parts stay separate: ∂J/∂C goes into the adjoint solves, ∂J/∂X straight to
the control (Wᵀ). Terms (:mod:`mscap.design.terms`) add and scale.

- :class:`Dissimilarity` d = −τ log Σ_{a<b} exp(−‖C_a − C_b‖²/τ), a soft minimum of the
  pairwise squared distances (pF²), evaluated as min D − τ log Σ exp(−(D − min D)/τ): no
  overflow or underflow to −log 0 at any D/τ, and min D − τ log(#pairs) ≤ d ≤ min D.
- :class:`SeparationBarrier` B = Σ b(d − g) over vertex–edge pairs of *different*
  outlines, and of outlines against the sheet boundary, with b the C² IPC barrier of
  :mod:`mscap.fem.elastic.contact` and d the point–segment distance (mm). The shift g is
  ``gap_mm`` between capacitors and ``margin_mm`` (default: the gap) to the sheet, so B
  is infinite exactly when the min gap is violated and zero once every d ≥ g + d̂
  (d̂ defaults to the gap: the barrier acts between one and two gaps). The sum is
  unweighted; a vertex close to another *vertex* is counted once per incident edge,
  which a barrier tolerates. Vertices meet their own outline's edges in B only across a
  neck (``feature_mm`` > 0, ``[optimizer] min_feature_mm``: farther apart along the
  outline than :data:`NECK_ARC` feature sizes; shift and d̂ the feature size);
  self-intersection is kept out by :meth:`SeparationBarrier.max_step`, which also bounds
  the other non-incident vertex–edge pairs of the same outline (shift 0), with the
  smoothing term discouraging the spikes that would bring them close.
- :class:`LaplacianSmoothing` S = Σ_i ‖x_i − (x_{i−1} + x_{i+1})/2‖² (mm²) over closed
  outlines, not length-normalised: invariant under rigid motions, ∝ scale², and for a
  smooth curve sampled at spacing h it falls like h³, so w_s must be chosen at the mesh's
  outline spacing. It also shrinks outlines slightly (a curve-shortening flow).

Why numpy rather than ipctk: ipctk's 2D barrier works on squared distances with its own
``dmin`` convention, its pair filter (``can_collide``) is a Python callback per
candidate, and its CCD stops at one absolute minimum distance, whereas the step bound
here keeps each pair above a fraction of its own current gap. The vectorised version
below is short, exact in mm, and adds no dependency. Broad phase: a
:class:`scipy.spatial.cKDTree` on all vertices with radius = longest capacitor edge +
shift + reach; the few sheet edges (possibly long) are paired with every capacitor
vertex.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Mapping

import numpy as np
from scipy.spatial import cKDTree

from mscap.design.history import HEAD, TAIL
from mscap.design.readback import (DesignPoses, ProtocolDissimilarity, ReconstructionBound, design_poses,
                                   read_back_estimate)
from mscap.design.terms import Sum, Term, Weighted, soft_min
from mscap.errors import GeometryError, MscapError
from mscap.fem.elastic.contact import barrier, barrier_derivatives
from mscap.geometry.polygons import along_outline, arc_positions, segment_projection
from mscap.scene.calibration import NoiseModel
from mscap.scene.settings import DISTANCES

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["soft_min", "Dissimilarity", "PlateAreaBarrier", "DISTANCES", "capacitance_term", "SeparationBarrier",
           "LaplacianSmoothing", "Weighted", "Sum", "INPUTS", "NamedTerm", "ObjectiveParts", "LayoutObjective",
           "layout_objective"]


@dataclass(frozen=True)
class Dissimilarity(Term):
    """Soft minimum (pF²) of pairwise squared distances of pose capacitance vectors."""

    tau_pF2: float = 1.0

    def __post_init__(self):
        if not self.tau_pF2 > 0:
            raise MscapError(f"[optimizer] tau_pF2 must be positive, got {self.tau_pF2!r}")

    def value_and_gradient(self, capacitance_pF: np.ndarray) -> tuple[float, np.ndarray]:
        """``d`` and ``∂d/∂C`` (pF), ``C`` of shape ``(n_poses, k)`` with n_poses ≥ 2."""
        c = np.asarray(capacitance_pF, dtype=float)
        if c.ndim != 2 or len(c) < 2:
            raise MscapError(f"capacitances must be (n_poses >= 2, k), got shape {c.shape}")
        # Differences, not the Gram trick: ~60 pF readings differ by ~1 pF.
        diff = c[:, None, :] - c[None, :, :]
        dist2 = np.einsum("abk,abk->ab", diff, diff)
        a, b = np.triu_indices(len(c), 1)
        pair = dist2[a, b]
        value, weight = soft_min(pair, self.tau_pF2)
        w = np.zeros_like(dist2)
        w[a, b] = weight  # ∂d/∂D_ab: a softmax, summing to 1
        w += w.T
        return value, 2 * np.einsum("ab,abk->ak", w, diff)


#: Two points of one outline form a neck (or a slot's two sides) when they are farther
#: apart along the outline than this many feature sizes: at 2π, a right-angled corner's
#: two sides never come within the barrier's reach (2 × feature) of each other, and a
#: corner sharper than 2 arcsin(1/2π) ≈ 18° cannot be kept.
NECK_ARC = 2 * np.pi


@dataclass(frozen=True, eq=False)
class SeparationBarrier(Term):
    """IPC barrier keeping capacitor outlines ``gap_mm`` apart and ``margin_mm`` inside the
    sheet. Outlines are closed ``(m_i, 2)`` arrays (mm); the sheet does not move. Assumes
    a feasible start (:func:`mscap.geometry.layout.check_layout`), which :meth:`max_step` keeps."""

    sheet_outline_mm: np.ndarray
    gap_mm: float
    dhat_mm: float | None = None
    margin_mm: float | None = None
    #: Narrowest neck or slot of a plate (mm; 0: none): two parts of one outline farther
    #: apart along it than :data:`NECK_ARC` times this stay this far apart, with the
    #: barrier acting over one more of it ([optimizer] min_feature_mm).
    feature_mm: float = 0.0
    sheet: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        dhat = self.gap_mm if self.dhat_mm is None else self.dhat_mm
        if not dhat > 0:
            raise MscapError(f"barrier d̂ must be positive, got {dhat!r} mm (with [capacitors] "
                             f"min_gap_mm = {self.gap_mm!r}, give dhat_mm explicitly)")
        object.__setattr__(self, "dhat_mm", float(dhat))
        object.__setattr__(self, "margin_mm", float(self.gap_mm if self.margin_mm is None
                                                    else self.margin_mm))
        object.__setattr__(self, "sheet", np.asarray(self.sheet_outline_mm, dtype=float))

    def _stack(self, outlines):
        """All vertices (capacitors, then the sheet, whose owner is ``len(outlines)``), the
        owner, next and previous vertex of each, and the outline sizes."""
        polygons = [np.asarray(o, dtype=float) for o in outlines] + [self.sheet]
        sizes = np.array([len(p) for p in polygons])
        start = np.repeat(np.cumsum(sizes) - sizes, sizes)
        size = np.repeat(sizes, sizes)
        local = np.arange(sizes.sum()) - start
        owner = np.repeat(np.arange(len(polygons)), sizes)
        return (np.vstack(polygons), owner, start + (local + 1) % size,
                start + (local - 1) % size, sizes)

    def _pairs(self, x, owner, nxt, prv, reach, same_outline, v=None, keep=0.0):
        """Vertex–edge pairs ``(p, e)`` (edge e runs from vertex e to ``nxt[e]``) that may
        come within ``shift + reach``, and which of them are a neck's (``feature_mm`` > 0:
        one outline's, farther apart along it than ``NECK_ARC · feature_mm``); other pairs
        within one outline only if ``same_outline``.
        Given velocities ``v``, also drop vertex pairs too far apart for their relative
        speed to close (1 − keep) of it: a pair (p, ab) is needed only if (1 − keep)(d − g)
        < L = ‖v_p − v_j‖ for the faster endpoint j, and d ≥ ‖x_p − x_j‖ − longest edge."""
        sheet = owner[-1]
        cap = owner != sheet
        longest = np.linalg.norm(x[nxt[cap]] - x[cap], axis=1).max()
        base = longest + max(self.gap_mm, self.margin_mm)
        # Vertex pairs of two outlines within reach of the gap, and (if wanted) of one outline
        # within reach of touching (no gap between an outline and itself): an outline's own
        # neighbours within the gap were 98 % of the pairs on poking's final outlines (8,115
        # vertices, 0.11 mm edges), and every array below was 50× longer for nothing.
        members = [np.flatnonzero(owner == o) for o in range(sheet + 1)]
        trees = [cKDTree(x[m]) for m in members]
        found = [np.empty((0, 2), dtype=np.intp)]
        for a in range(len(members)):
            for b in range(a + 1, len(members)):
                near = trees[a].sparse_distance_matrix(trees[b], base + reach, output_type="ndarray")
                found.append(np.c_[members[a][near["i"]], members[b][near["j"]]])
        i, j = np.concatenate(found).T
        gap = np.full(len(i), base)
        own = longest + self.feature_mm  # an outline's own pairs: no gap, or a neck's
        necking = self.feature_mm > 0
        if necking:
            arc, perimeter = arc_positions(x, owner, nxt)
        if same_outline or necking:  # the capacitors' own pairs (the sheet's own edges never enter)
            radius = own + (reach if same_outline else self.feature_mm)
            si, sj = np.concatenate([members[o][trees[o].query_pairs(radius, output_type="ndarray")]
                                     for o in range(sheet)] + [np.empty((0, 2), dtype=np.intp)]).T
            if not same_outline:  # only a neck's; a vertex is an end of each edge it pairs with below
                far = along_outline(arc, perimeter, si, sj) > NECK_ARC * self.feature_mm
                si, sj = si[far], sj[far]
            i, j, gap = np.r_[i, si], np.r_[j, sj], np.r_[gap, np.full(len(si), own)]
        if v is not None:
            apart = np.linalg.norm(x[i] - x[j], axis=1) - gap
            closing = np.linalg.norm(v[i] - v[j], axis=1) / (1 - keep)
            i, j = i[apart < closing], j[apart < closing]
        p, e = np.r_[i, i, j, j], np.r_[j, prv[j], i, prv[i]]
        p, e = p[cap[e]], e[cap[e]]  # sheet edges are added below, all of them
        on_sheet = np.flatnonzero(~cap)
        p = np.r_[p, np.repeat(np.flatnonzero(cap), len(on_sheet))]
        e = np.r_[e, np.tile(on_sheet, cap.sum())]
        same = owner[p] == owner[e]
        necks = np.zeros(len(p), dtype=bool)
        if necking:  # farther apart along the outline than NECK_ARC feature sizes, to e's nearer end
            ends = np.minimum(along_outline(arc, perimeter, p, e), along_outline(arc, perimeter, p, nxt[e]))
            necks = same & (ends > NECK_ARC * self.feature_mm)
        use = ~same | necks
        if same_outline:
            use |= same & (p != e) & (p != nxt[e])
        code, index = np.unique(p[use] * len(x) + e[use], return_index=True)
        return code // len(x), code % len(x), necks[use][index]

    def _shift(self, owner, p, e, necks):
        """The gap each pair must keep: ``gap_mm`` between capacitors, ``margin_mm`` to the
        sheet, ``feature_mm`` across a neck (``necks``), none within an outline otherwise."""
        sheet = owner[-1]
        shift = np.where((owner[p] == sheet) | (owner[e] == sheet), self.margin_mm, self.gap_mm)
        return np.where(owner[p] == owner[e], np.where(necks, self.feature_mm, 0.0), shift)

    def _dhat(self, necks):
        """The barrier's reach per pair: ``feature_mm`` across a neck, ``dhat_mm`` elsewhere."""
        return np.where(necks, self.feature_mm, self.dhat_mm)

    def _violation(self, owner, p, e, s, necks):
        bad = np.flatnonzero(s <= 0)
        if len(bad):
            i, j = sorted((int(owner[p[bad[0]]]), int(owner[e[bad[0]]])))
            if necks[bad[0]]:
                raise GeometryError(f"capacitor {i} has a neck or slot narrower than [optimizer] min_feature_mm "
                                    f"= {self.feature_mm:g} (by {-s[bad[0]]:.3g} mm)", i)
            what = "the sheet edge" if j == owner[-1] else f"capacitor {j}"
            raise GeometryError(f"capacitor {i} violates the minimum gap to {what} "
                                f"(by {-s[bad[0]]:.3g} mm)", i)

    def value(self, outlines) -> float:
        """B (mm²); ``inf`` when a minimum gap, margin or feature size is violated."""
        x, owner, nxt, prv, _ = self._stack(outlines)
        p, e, necks = self._pairs(x, owner, nxt, prv, self.dhat_mm, False)
        d, _, _ = segment_projection(x[p], x[e], x[nxt[e]])
        return float(barrier(d - self._shift(owner, p, e, necks), self._dhat(necks)).sum())

    def value_and_gradient(self, outlines):
        """B and a tuple of ``(m_i, 2)`` gradients (mm); raises GeometryError if infeasible."""
        x, owner, nxt, prv, sizes = self._stack(outlines)
        p, e, necks = self._pairs(x, owner, nxt, prv, self.dhat_mm, False)
        d, t, r = segment_projection(x[p], x[e], x[nxt[e]])
        s = d - self._shift(owner, p, e, necks)
        self._violation(owner, p, e, s, necks)
        dhat = self._dhat(necks)
        on = s < dhat
        p, e, d, t, r, s, dhat = p[on], e[on], d[on], t[on], r[on], s[on], dhat[on]
        # ∂d/∂p = n, ∂d/∂a = −(1 − t) n, ∂d/∂b = −t n (t is optimal, so its variation drops).
        force = (barrier_derivatives(s, dhat)[0] / d)[:, None] * r
        grad = np.zeros_like(x)
        np.add.at(grad, p, force)
        np.add.at(grad, e, -(1 - t)[:, None] * force)
        np.add.at(grad, nxt[e], -t[:, None] * force)
        value = float(barrier(s, dhat).sum())
        return value, tuple(np.split(grad, np.cumsum(sizes)[:-1])[:-1])

    def max_step(self, outlines, directions, keep: float = 0.1, iterations: int = 50) -> float:
        """Largest α ∈ [0, 1] (conservative) such that along ``x + α v`` no vertex–edge
        shifted distance s = d − g (capacitor–capacitor, capacitor–sheet, and
        non-incident within an outline with g = 0) drops below ``keep`` times its current
        value.

        Additive CCD (Li et al. 2021) per pair: d is Lipschitz in α with constant
        L = max(‖v_p − v_a‖, ‖v_p − v_b‖) (the relative speed of p and any point of ab),
        so from α_n it stays above the target for (d(α_n) − target)/L; stepping 0.99
        times that never crosses it, and a head-on approach converges in a few steps.
        """
        if not 0 <= keep < 1:
            raise MscapError(f"keep must be in [0, 1), got {keep!r}")
        x, owner, nxt, prv, _ = self._stack(outlines)
        v = np.vstack([np.asarray(o, dtype=float) for o in directions] + [0 * self.sheet])
        speed = np.linalg.norm(v, axis=1).max()
        if speed == 0:
            return 1.0
        p, e, necks = self._pairs(x, owner, nxt, prv, 2 * speed / (1 - keep), True, v, keep)
        b = nxt[e]
        d, _, _ = segment_projection(x[p], x[e], x[b])
        shift = self._shift(owner, p, e, necks)
        self._violation(owner, p, e, d - shift, necks)
        target = shift + keep * (d - shift)
        lipschitz = np.maximum(np.linalg.norm(v[p] - v[e], axis=1),
                               np.linalg.norm(v[p] - v[b], axis=1))
        near = lipschitz > d - target  # may reach the target within α ≤ 1
        p, e, b, target, lipschitz = p[near], e[near], b[near], target[near], lipschitz[near]
        alpha, ceiling = np.zeros(len(p)), 1.0
        for _ in range(iterations):
            # A pair that has stalled caps the answer; pairs already past the cap can't lower it.
            live = alpha < ceiling
            p, e, b, target, lipschitz, alpha = (a[live] for a in (p, e, b, target, lipschitz, alpha))
            if not len(p):
                break
            d, _, _ = segment_projection(x[p] + alpha[:, None] * v[p], x[e] + alpha[:, None] * v[e],
                                         x[b] + alpha[:, None] * v[b])
            step = 0.99 * np.maximum(d - target, 0.0) / lipschitz
            alpha = alpha + step
            if (step < 1e-9).any():
                ceiling = min(ceiling, float(alpha[step < 1e-9].min()))
        return min(ceiling, float(alpha.min())) if len(alpha) else ceiling


@dataclass(frozen=True)
class LaplacianSmoothing(Term):
    """S = Σ_i ‖x_i − (x_{i−1} + x_{i+1})/2‖² over closed outlines (mm²)."""

    def value_and_gradient(self, outlines):
        value, grads = 0.0, []
        for outline in outlines:
            o = np.asarray(outline, dtype=float)
            lap = o - 0.5 * (np.roll(o, 1, axis=0) + np.roll(o, -1, axis=0))
            value += float(np.sum(lap * lap))
            # S = ‖L x‖² with L symmetric (circulant), so ∇S = 2 L (L x).
            grads.append(2 * (lap - 0.5 * (np.roll(lap, 1, axis=0) + np.roll(lap, -1, axis=0))))
        return value, tuple(grads)


#: What a term reads: the capacitances ``(n_poses, k)`` or the outlines.
INPUTS = ("capacitance", "outlines")


@dataclass(frozen=True)
class NamedTerm:
    """One term of J by name: J adds ``weight × term(input)``, ``of`` the term's input
    (:data:`INPUTS`). The name is its history column (:mod:`mscap.design.history`)."""

    name: str
    term: Term
    weight: float
    of: str

    def __post_init__(self):
        if not (self.name.isidentifier() and self.name.isascii()) or self.name in HEAD + TAIL:
            raise MscapError(f"an objective term's name must be an ASCII identifier and not a history column of "
                             f"its own ({', '.join(HEAD + TAIL)}), got {self.name!r}")
        if self.of not in INPUTS:
            raise MscapError(f"objective term {self.name!r} reads {self.of!r}, not one of {', '.join(INPUTS)}")
        if not np.isfinite(self.weight):
            raise MscapError(f"objective term {self.name!r} has weight {self.weight!r}")

    def weighted(self, value: float) -> float:
        """``weight × value`` (0 for a zero weight, even where the term is infinite)."""
        return 0.0 if self.weight == 0 else self.weight * value


@dataclass(frozen=True)
class ObjectiveParts:
    """J and its terms, unweighted, by name (``d`` in pF², noise units or −mm; the
    barriers; the smoothing in mm²)."""

    J: float
    terms: Mapping[str, float]


@dataclass(frozen=True)
class LayoutObjective:
    """The design objective — the one place J is composed, from its terms by name:

        J(C, outlines) = Σ_t w_t t(C or outlines)

    by default −d(C) + w_b B(outlines) [+ w_b B_area(outlines)] + w_s S(outlines)
    (:func:`layout_objective`). A new term is its :class:`~mscap.design.terms.Term`, its
    weight and its name: the evaluation, the history, the store and the progress lines
    carry it by that name. ``separation`` is the separation barrier B, which also bounds
    the line search's step."""

    terms: tuple[NamedTerm, ...]
    separation: SeparationBarrier

    def __post_init__(self):
        names = [t.name for t in self.terms]
        if len(set(names)) != len(names) or "d" not in names:
            raise MscapError(f"an objective's terms need distinct names and a capacitance term 'd', got {names}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.terms)

    def _of(self, of: str) -> tuple[NamedTerm, ...]:
        return tuple(t for t in self.terms if t.of == of)

    @staticmethod
    def _weighted(terms: tuple[NamedTerm, ...]) -> Term:
        parts = [t.weight * t.term for t in terms]
        return parts[0] if len(parts) == 1 else Sum(tuple(parts))

    @property
    def capacitance(self) -> Term:
        """The capacitance part of J (by default −d)."""
        return self._weighted(self._of("capacitance"))

    @property
    def geometry(self) -> Term:
        """The outline part of J (by default w_b (B + B_area) + w_s S)."""
        return self._weighted(self._of("outlines"))

    def outline_terms(self, outlines, check: bool = False) -> dict[str, float]:
        """The outline terms, unweighted, by name. With ``check``, raise
        :class:`GeometryError` where one is infinite (outlines closer than the minimum gap,
        plates over the area limit): a design evaluates this before any simulation."""
        values = {}
        for t in self._of("outlines"):
            values[t.name] = float(t.term.value(outlines))
            if check and not np.isfinite(values[t.name]):
                raise GeometryError(f"the outlines at this design make the objective's {t.name} term "
                                    f"{values[t.name]} (outlines closer than the minimum gap, or plates over "
                                    f"[optimizer] max_plate_area_mm2)")
        return values

    def parts(self, capacitance_pF: np.ndarray, outline_terms: Mapping[str, float]) -> ObjectiveParts:
        """J and its terms at capacitances ``(n_poses, k)`` and :meth:`outline_terms`."""
        values = {t.name: float(t.term.value(capacitance_pF)) for t in self._of("capacitance")}
        return self._parts(values, outline_terms)

    def parts_and_gradient(self, capacitance_pF: np.ndarray,
                           outline_terms: Mapping[str, float]) -> tuple[ObjectiveParts, np.ndarray]:
        """:meth:`parts` and ∂J/∂C ``(n_poses, k)`` from one evaluation of each capacitance term."""
        values, dJ_dC = {}, None
        for t in self._of("capacitance"):
            v, g = t.term.value_and_gradient(capacitance_pF)
            values[t.name] = float(v)
            dJ_dC = t.weight * g if dJ_dC is None else dJ_dC + t.weight * g
        return self._parts(values, outline_terms), dJ_dC

    def _parts(self, capacitance_terms: Mapping[str, float], outline_terms: Mapping[str, float]) -> ObjectiveParts:
        values = {**capacitance_terms, **outline_terms}
        J = 0.0
        for t in self.terms:
            J = J + t.weighted(values[t.name])
        return ObjectiveParts(float(J), {name: float(values[name]) for name in self.names})

    def capacitance_value(self, terms: Mapping[str, float]) -> float:
        """The capacitance part of J from the terms' values ``terms``."""
        return float(sum(t.weighted(terms[t.name]) for t in self._of("capacitance")))

    def value(self, capacitance_pF: np.ndarray, outlines) -> float:
        return self.parts(capacitance_pF, self.outline_terms(outlines)).J

    def max_step(self, outlines, directions, keep: float = 0.1) -> float:
        return self.separation.max_step(outlines, directions, keep)


def capacitance_term(scene: Scene, designed: DesignPoses | None = None) -> Term:
    """The term d of the scene, maximised (J = −d + ...), over its design poses
    ``designed`` (default: :func:`~mscap.design.readback.design_poses`):

    - ``"pF"``: :class:`Dissimilarity` (``tau_pF2``);
    - ``"noise"``: :class:`mscap.design.readback.ProtocolDissimilarity` (``tau_noise``), pairwise
      distances in the read-out noise of the ``[calibration]`` protocol (tared when it
      names a reference pose, else raw; appendix A's noise without a calibration);
    - ``"reconstruction"``: minus :class:`mscap.design.readback.ReconstructionBound` (``tau_mm``),
      so d = −bound (mm); needs design poses from the calibration family;
    - ``"readback"``: minus :class:`mscap.design.readback.ReadbackError`, the bound ⊕ the noise of
      the calibration's map fitted on the grid (mm); the same poses.
    """
    settings = scene.optimizer
    if settings.distance == "pF":
        return Dissimilarity(settings.tau_pF2)
    designed = designed or design_poses(scene)
    if settings.distance == "reconstruction":  # design_poses checked there is a family
        return -1.0 * ReconstructionBound(designed.family, settings.tau_mm)
    if settings.distance == "readback":
        return -1.0 * read_back_estimate(scene, designed)
    cal = scene.calibration
    noise = cal.noise if cal is not None else NoiseModel()
    reference = None
    if designed.family is not None:
        reference = designed.family.reference_row
    elif cal is not None and cal.reference is not None:
        reference = list(designed.names).index(cal.reference)
    return ProtocolDissimilarity(noise, reference, settings.tau_noise)


@dataclass(frozen=True)
class PlateAreaBarrier(Term):
    """Barrier on the total plate area (the paper's "limited capacitor area"):
    b(1 − A/A_max) with the IPC barrier of :mod:`mscap.fem.elastic.contact` (d̂ = ``dhat``, relative),
    zero while A ≤ (1 − d̂) A_max, infinite at A ≥ A_max; A = Σ_j |area of outline j| (mm²)."""

    max_area_mm2: float
    dhat: float = 0.1

    @staticmethod
    def areas(outlines) -> np.ndarray:
        """Signed area (mm²) of each closed outline (shoelace)."""
        return np.array([0.5 * np.sum(o[:, 0] * np.roll(o[:, 1], -1) - np.roll(o[:, 0], -1) * o[:, 1])
                         for o in (np.asarray(x, dtype=float) for x in outlines)])

    def value_and_gradient(self, outlines):
        signed = self.areas(outlines)
        slack = 1.0 - np.abs(signed).sum() / self.max_area_mm2
        if slack <= 0:
            raise GeometryError(f"the plates' total area {np.abs(signed).sum():.6g} mm² reaches "
                                f"[optimizer] max_plate_area_mm2 = {self.max_area_mm2:g}")
        value = float(barrier(np.array([slack]), self.dhat)[0])
        db = barrier_derivatives(np.array([slack]), self.dhat)[0][0] * (-1.0 / self.max_area_mm2)
        grads = []
        for o, a in zip(outlines, signed):
            o = np.asarray(o, dtype=float)
            d_signed = 0.5 * np.c_[np.roll(o[:, 1], -1) - np.roll(o[:, 1], 1), np.roll(o[:, 0], 1) - np.roll(o[:, 0], -1)]
            grads.append(db * np.sign(a) * d_signed)
        return value, tuple(grads)

    def value(self, outlines) -> float:
        slack = 1.0 - np.abs(self.areas(outlines)).sum() / self.max_area_mm2
        return float(barrier(np.array([slack]), self.dhat)[0])


def layout_objective(scene: Scene, dhat_mm: float | None = None, *,
                     designed: DesignPoses | None = None) -> LayoutObjective:
    """J = −d + w_b (B + B_area) + w_s S from a scene's ``[optimizer]`` (``distance``,
    ``tau_pF2`` / ``tau_noise`` / ``tau_mm``, ``barrier_weight``, ``smoothing_weight``,
    ``max_plate_area_mm2``, ``min_feature_mm``) and ``[capacitors] min_gap_mm``; the terms
    named ``d``, ``barrier``, ``area`` (with an area limit) and ``smoothing``; d over the
    design poses ``designed`` (default: the scene's)."""
    settings = scene.optimizer
    separation = SeparationBarrier(scene.sheet_outline_mm, scene.min_gap_mm, dhat_mm,
                                   feature_mm=settings.min_feature_mm)
    terms = [NamedTerm("d", capacitance_term(scene, designed), -1.0, "capacitance"),
             NamedTerm("barrier", separation, settings.barrier_weight, "outlines")]
    if settings.max_plate_area_mm2 > 0:
        terms.append(NamedTerm("area", PlateAreaBarrier(settings.max_plate_area_mm2), settings.barrier_weight,
                               "outlines"))
    terms.append(NamedTerm("smoothing", LaplacianSmoothing(), settings.smoothing_weight, "outlines"))
    return LayoutObjective(tuple(terms), separation)
