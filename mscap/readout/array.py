"""Multiplexed read-out of a capacitor array (paper appendix C).

The top plates of an m × n array are joined by column (n column leads), the bottom
plates by row (m row leads). Each lead is switched to GND (0) or LOGIC (1) by its own
SPDT switch; capacitor ij is active iff its two leads differ, ``c_ij = a_j XOR b_i``. One
lead pattern gives one reading

    r = Σ_active C_ij + n_ON · C_ON + n_OFF · C_OFF,

where a switch is *ON* when its lead is at LOGIC and *OFF* at GND, so ``n_ON`` is the
number of leads at 1 and ``n_ON + n_OFF = m + n``. Stacking p patterns gives ``M γ = r``
with the unknowns ``γ = (C of each capacitor, in capacitor order; C_ON; C_OFF)``.

A pattern is a row of ``m + n`` bits: the row leads ``b_0 … b_{m-1}`` first, then the
column leads ``a_0 … a_{n-1}``. Which patterns to read: :mod:`mscap.readout.patterns`.
``docs/readout.md`` has the measured numbers.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from mscap.errors import ReadoutError
from mscap.scene.calibration import NoiseModel

__all__ = ["ReadoutError", "C_ON_PF", "C_OFF_PF", "MAX_ALL_LEADS", "MAX_DEFAULT_ALL_LEADS",
           "MAX_ENUMERATED_CANDIDATE_LEADS", "MAX_RANDOM_CANDIDATES", "CapacitorArray", "grid_array", "read_wiring",
           "all_patterns", "random_patterns", "MeasurementMatrix", "measurement_matrix", "check_rank", "Recovered",
           "ideal_readings", "recover", "noise_gain", "error_bound", "ReadoutErrors",
           "simulate_readout", "check_switches"]

log = logging.getLogger(__name__)

#: Parasitic capacitance of one SPDT switch (ADG333A) ON and OFF, paper appendix C (pF).
C_ON_PF = 35.0
C_OFF_PF = 12.0
#: A fabrication.json is some kB; ``read_wiring`` reads at most this much of one.
MAX_WIRING_BYTES = 64 * 2**20
#: Rows or columns of a wiring file: no design has more capacitors (the scene's bound).
MAX_WIRING_LEADS = 100
#: ``all_patterns`` refuses arrays with more leads (2**20 patterns).
MAX_ALL_LEADS = 20
#: The default pattern set is every pattern up to this many leads (2**10 readings).
MAX_DEFAULT_ALL_LEADS = 10
#: ``optimise_patterns`` draws its candidates from every pattern up to this many leads,
#: else from ``MAX_RANDOM_CANDIDATES`` random ones.
MAX_ENUMERATED_CANDIDATE_LEADS = 11
MAX_RANDOM_CANDIDATES = 1024
# A null-space projector entry above this ties unknowns together (a singular value below
# s_max · max(M.shape) · eps counts as zero, numpy's rule, see MeasurementMatrix.rank).
_NULL_TOL = 1e-9


# ---------------------------------------------------------------- the array
@dataclass(frozen=True)
class CapacitorArray:
    """How the capacitors of a design are wired: ``rows`` × ``columns`` slots.

    ``slots[i] = (row, column)`` is the slot of capacitor i; slots holding no capacitor
    stay empty (their leads still exist but add nothing).
    """

    rows: int
    columns: int
    slots: tuple[tuple[int, int], ...]

    def __post_init__(self):
        if self.rows < 1 or self.columns < 1:
            raise ReadoutError(f"array: rows and columns must be >= 1, got {self.rows} x {self.columns}")
        if not self.slots:
            raise ReadoutError("array: no capacitors")
        for i, (r, c) in enumerate(self.slots):
            if not (0 <= r < self.rows and 0 <= c < self.columns):
                raise ReadoutError(f"array: capacitor {i} in slot [{r},{c}] outside the "
                                   f"{self.rows} x {self.columns} array")
        if len(set(self.slots)) < len(self.slots):
            seen = {}
            for i, slot in enumerate(self.slots):
                if slot in seen:
                    raise ReadoutError(f"array: capacitors {seen[slot]} and {i} share slot [{slot[0]},{slot[1]}]")
                seen[slot] = i

    @property
    def k(self) -> int:
        """Number of capacitors."""
        return len(self.slots)

    @property
    def n_leads(self) -> int:
        """``rows + columns``: the bits of a pattern."""
        return self.rows + self.columns

    @property
    def n_unknowns(self) -> int:
        """``k + 2``: the capacitors, C_ON and C_OFF."""
        return self.k + 2

    @property
    def unknown_names(self) -> tuple[str, ...]:
        """``("C[0,0] (capacitor 0)", …, "C_ON", "C_OFF")``, the order of γ."""
        return tuple(f"C[{r},{c}] (capacitor {i})" for i, (r, c) in enumerate(self.slots)) + ("C_ON", "C_OFF")

    def grid(self) -> np.ndarray:
        """``(rows, columns)`` capacitor index per slot, -1 where empty."""
        grid = np.full((self.rows, self.columns), -1, dtype=np.int64)
        for i, (r, c) in enumerate(self.slots):
            grid[r, c] = i
        return grid


def grid_array(k: int, rows: int | None = None, columns: int | None = None) -> CapacitorArray:
    """The default wiring of ``k`` capacitors: filled row by row.

    Without ``rows``/``columns``: ``rows = ceil(sqrt(k))``, ``columns = ceil(k / rows)``;
    given one, the other is the smallest that fits. Capacitor i sits in slot
    ``(i // columns, i % columns)``.

    Raises
    ------
    ReadoutError
        ``k < 1`` or the ``rows`` × ``columns`` array has fewer than k slots.
    """
    if k < 1:
        raise ReadoutError(f"array: need at least one capacitor, got k = {k}")
    if rows is None and columns is None:
        rows = math.isqrt(k - 1) + 1
    if (rows is not None and rows < 1) or (columns is not None and columns < 1):
        raise ReadoutError(f"array: rows and columns must be >= 1, got rows = {rows}, columns = {columns}")
    if (rows is not None and rows > k) or (columns is not None and columns > k):
        raise ReadoutError(f"array: rows and columns must be <= k = {k} (a lead beyond it joins no capacitor), "
                           f"got rows = {rows}, columns = {columns}")
    rows = rows if rows is not None else -(-k // columns)
    columns = columns if columns is not None else -(-k // rows)
    if rows * columns < k:
        raise ReadoutError(f"array: {k} capacitors do not fit a {rows} x {columns} array (rows x columns < k)")
    return CapacitorArray(rows, columns, tuple((i // columns, i % columns) for i in range(k)))


def read_wiring(path, k: int) -> CapacitorArray:
    """The array of a routed design: ``array`` of ``mscap fabricate``'s
    ``fabrication.json`` (``rows``, ``columns``, ``slots``: each ``capacitor`` with its
    ``row`` and ``column``), for a design of ``k`` capacitors.

    Raises
    ------
    ReadoutError
        Unreadable, not such a file, or not a wiring of these k capacitors (named).
    """
    import json

    from mscap.infile import read_regular

    try:
        text = read_regular(path, MAX_WIRING_BYTES, "a fabrication.json")
    except OSError as exc:
        raise ReadoutError(f"--wiring {path}: cannot read it ({exc.strerror})") from None
    except ValueError as exc:  # a FIFO, a device, a directory, too large
        raise ReadoutError(f"--wiring {path}: {exc}") from None
    try:
        array = json.loads(text)["array"]
        rows, columns = array["rows"], array["columns"]
        slots = {int(s["capacitor"]): (s["row"], s["column"]) for s in array["slots"]}
    except (ValueError, KeyError, TypeError) as exc:
        raise ReadoutError(f"--wiring {path}: not an `mscap fabricate` fabrication.json (array.rows, "
                           f"array.columns, array.slots: {type(exc).__name__} {exc})") from None
    values = [rows, columns] + [v for slot in slots.values() for v in slot]
    if not all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= MAX_WIRING_LEADS for v in values):
        raise ReadoutError(f"--wiring {path}: array.rows, array.columns and every slot's row and column must be "
                           f"whole numbers in 0..{MAX_WIRING_LEADS}")
    if sorted(slots) != list(range(k)):
        raise ReadoutError(f"--wiring {path}: wires capacitors {sorted(slots)}, the design has {k} (0..{k - 1})")
    return CapacitorArray(rows, columns, tuple(slots[c] for c in range(k)))


# ---------------------------------------------------------------- patterns
def all_patterns(array: CapacitorArray) -> np.ndarray:
    """Every lead pattern, ``(2**(m+n), m+n)`` 0/1, lead 0 the most significant bit.

    Raises
    ------
    ReadoutError
        More than ``MAX_ALL_LEADS`` leads.
    """
    n = array.n_leads
    if n > MAX_ALL_LEADS:
        raise ReadoutError(f"all patterns: a {array.rows} x {array.columns} array has {n} leads, i.e. "
                           f"2**{n} patterns; at most {MAX_ALL_LEADS} leads (use optimised patterns)")
    return ((np.arange(2 ** n)[:, None] >> np.arange(n - 1, -1, -1)) & 1).astype(np.int8)


def random_patterns(array: CapacitorArray, count: int, seed: int = 0) -> np.ndarray:
    """Up to ``count`` distinct random patterns (fewer if duplicates were drawn), sorted."""
    bits = np.random.default_rng(seed).integers(0, 2, (count, array.n_leads), dtype=np.int8)
    return np.unique(bits, axis=0)


def _checked_patterns(array: CapacitorArray, patterns) -> np.ndarray:
    bits = np.asarray(patterns)
    if bits.ndim != 2 or bits.shape[1] != array.n_leads or len(bits) == 0:
        raise ReadoutError(f"patterns: expected shape (p >= 1, {array.n_leads}) ({array.rows} row leads "
                           f"then {array.columns} column leads), got {bits.shape}")
    if not np.isin(bits, (0, 1)).all():
        raise ReadoutError(f"patterns: lead states must be 0 (GND) or 1 (LOGIC), got {np.unique(bits)}")
    return bits.astype(np.int8)


def _rows(array: CapacitorArray, bits: np.ndarray) -> np.ndarray:
    """The rows of M for 0/1 patterns ``bits`` (no checks)."""
    row, column = np.array(array.slots).T
    active = bits[:, row] ^ bits[:, array.rows + column]
    n_on = bits.sum(axis=1, dtype=np.int64)
    return np.column_stack([active, n_on, array.n_leads - n_on]).astype(float)


# ---------------------------------------------------------------- the linear system
@dataclass(frozen=True, eq=False)
class MeasurementMatrix:
    """``M`` of a pattern set: one row per pattern, one column per unknown
    (``array.unknown_names``)."""

    array: CapacitorArray
    patterns: np.ndarray
    matrix: np.ndarray

    @cached_property
    def _svd(self) -> tuple[np.ndarray, np.ndarray]:
        _, s, vt = np.linalg.svd(self.matrix, full_matrices=True)
        return s, vt

    @property
    def rank(self) -> int:
        """Numerical rank (numpy's tolerance: s_max · max(p, u) · eps)."""
        s, _ = self._svd
        return int((s > s.max() * max(self.matrix.shape) * np.finfo(float).eps).sum())

    @property
    def condition_number(self) -> float:
        """2-norm condition number s_max / s_min (inf when rank deficient)."""
        s, _ = self._svd
        return float(s[0] / s[-1]) if self.rank == self.array.n_unknowns else math.inf

    def null_space(self) -> np.ndarray:
        """Orthonormal rows spanning the null space, ``(u - rank, u)``."""
        return self._svd[1][self.rank:]


def measurement_matrix(array: CapacitorArray, patterns) -> MeasurementMatrix:
    """``M`` for ``patterns`` (p, m+n): per row the XOR indicator of each capacitor, then
    n_ON (leads at 1) and n_OFF (leads at 0)."""
    bits = _checked_patterns(array, patterns)
    bits.setflags(write=False)
    matrix = _rows(array, bits)
    matrix.setflags(write=False)
    return MeasurementMatrix(array, bits, matrix)


def _join(names: list[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _inseparable(m: MeasurementMatrix) -> list[str]:
    """One sentence per group of unknowns that the readings do not separate."""
    null = m.null_space()
    projector = null.T @ null          # basis-independent: P_ij != 0 ties unknowns i and j
    names = m.array.unknown_names
    linked = np.abs(projector) > _NULL_TOL
    unassigned = set(np.flatnonzero(np.diag(projector) > _NULL_TOL))
    zero, sentences = [], []
    while unassigned:
        group, frontier = set(), {min(unassigned)}
        while frontier:
            group |= frontier
            frontier = set(np.flatnonzero(linked[list(frontier)].any(axis=0))) - group
        unassigned -= group
        group = sorted(group)
        who = _join([names[j] for j in group])
        columns = m.matrix[:, group]
        if len(group) == 1:            # P e_j = e_j: column j of M is zero
            zero.append(names[group[0]])
        elif np.all(columns == columns[:, :1]):
            sentences.append(f"{who} enter every reading together (identical columns of M)")
        else:
            missing = np.linalg.matrix_rank(null[:, group])
            sentences.append(f"{who} cannot be separated: the readings determine only "
                             f"{len(group) - missing} combination(s) of these {len(group)} unknowns")
    if zero:
        sentences.insert(0, f"{_join(zero)} never enter{'s' if len(zero) == 1 else ''} a reading "
                            f"(zero column{'' if len(zero) == 1 else 's'} of M)")
    return sentences


def check_rank(m: MeasurementMatrix) -> float:
    """Return the condition number of ``m``, or refuse a rank-deficient pattern set.

    Raises
    ------
    ReadoutError
        ``rank(M) <`` the number of unknowns; the message names the capacitances
        (``C[row,column] (capacitor i)``, ``C_ON``, ``C_OFF``) the readings cannot separate.
    """
    u, (p, _) = m.array.n_unknowns, m.matrix.shape
    if m.rank < u:
        few = f" (only {p} readings)" if p < u else ""
        raise ReadoutError(f"pattern set of {p} readings has rank {m.rank} < {u} unknowns{few}, condition number "
                           f"inf: " + "; ".join(_inseparable(m)))
    return m.condition_number


@dataclass(frozen=True, eq=False)
class Recovered:
    """Least-squares capacitances (..., k) and switch parasitics (...), pF."""

    capacitance_pF: np.ndarray
    c_on_pF: np.ndarray
    c_off_pF: np.ndarray


def ideal_readings(m: MeasurementMatrix, capacitance_pF, c_on_pF: float = C_ON_PF,
                   c_off_pF: float = C_OFF_PF) -> np.ndarray:
    """Noise-free readings ``M γ`` (..., p) of capacitances (..., k)."""
    capacitance = np.asarray(capacitance_pF, dtype=float)
    k = m.array.k
    if capacitance.ndim < 1 or capacitance.shape[-1] != k:
        raise ReadoutError(f"capacitances: expected (..., {k}) for {k} capacitors, got shape {capacitance.shape}")
    parasitic = m.matrix[:, k] * c_on_pF + m.matrix[:, k + 1] * c_off_pF
    return capacitance @ m.matrix[:, :k].T + parasitic


def recover(m: MeasurementMatrix, readings) -> Recovered:
    """Solve ``M γ = r`` in the least-squares sense for readings (..., p).

    Raises
    ------
    ReadoutError
        The pattern set is rank deficient (see ``check_rank``) or the readings do not
        match it.
    """
    check_rank(m)
    r = np.asarray(readings, dtype=float)
    p, u = m.matrix.shape
    if r.ndim < 1 or r.shape[-1] != p:
        raise ReadoutError(f"readings: expected (..., {p}) for {p} patterns, got shape {r.shape}")
    gamma = np.linalg.lstsq(m.matrix, r.reshape(-1, p).T, rcond=None)[0].T.reshape(r.shape[:-1] + (u,))
    k = m.array.k
    return Recovered(gamma[..., :k], gamma[..., k], gamma[..., k + 1])


def noise_gain(m: MeasurementMatrix) -> np.ndarray:
    """Per unknown, ``sqrt(((MᵀM)⁻¹)_jj)``: the error std per unit std of independent
    reading noise (< 1: the overdetermined system averages the noise down)."""
    check_rank(m)
    return np.sqrt(np.diag(np.linalg.inv(m.matrix.T @ m.matrix)))


def error_bound(m: MeasurementMatrix, additive_pF: float) -> float:
    """``‖M⁺‖_∞ · additive_pF``: no recovered unknown is off by more when every reading
    is off by at most ``additive_pF``."""
    check_rank(m)
    return float(np.abs(np.linalg.pinv(m.matrix)).sum(axis=1).max() * additive_pF)


# ---------------------------------------------------------------- noisy read-outs
@dataclass(frozen=True, eq=False)
class ReadoutErrors:
    """Recovered minus (shifted) true values of ``runs`` simulated read-outs.

    Arrays lead with the run axis: ``(runs, [poses,] k)`` for capacitors and
    ``(runs, [poses])`` for C_ON, C_OFF and the summaries.
    """

    true_capacitance_pF: np.ndarray
    capacitance_error_pF: np.ndarray
    c_on_error_pF: np.ndarray
    c_off_error_pF: np.ndarray

    @property
    def max_abs_pF(self) -> np.ndarray:
        """Largest |error| over the capacitors, per run (and pose)."""
        return np.abs(self.capacitance_error_pF).max(axis=-1)

    @property
    def rms_pF(self) -> np.ndarray:
        """RMS error over the capacitors, per run (and pose)."""
        return np.sqrt(np.mean(self.capacitance_error_pF ** 2, axis=-1))


def check_switches(c_on_pF: float, c_off_pF: float) -> None:
    """The switches' parasitic capacitances must be finite and >= 0 pF (0: an ideal
    switch). Their order is free: C_ON and C_OFF are separate unknowns whatever their
    values (their columns n_ON and n_OFF = leads − n_ON are independent), so a switch
    with C_OFF > C_ON reads back as well."""
    for name, value in (("C_ON (--c-on)", c_on_pF), ("C_OFF (--c-off)", c_off_pF)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ReadoutError(f"switches: {name} must be a finite capacitance >= 0 pF, got {value!r}")


def simulate_readout(m: MeasurementMatrix, capacitance_pF, c_on_pF: float = C_ON_PF, c_off_pF: float = C_OFF_PF,
                     noise: NoiseModel = NoiseModel()) -> ReadoutErrors:
    """Read ``capacitance_pF`` (k,) or (poses, k) ``noise.runs`` times and recover it.

    ``noise`` is the project's noise model (:class:`mscap.scene.calibration.NoiseModel`):
    the relative shift acts on each capacitor once per run (a fabrication/drift shift the
    read-out cannot and should not remove), the additive draw on every reading.

    A run shifts each capacitor once (the same shift in every pose: one fabricated
    sensor), then reads every pose with fresh additive noise on each reading. The
    errors are against the shifted truth; C_ON and C_OFF are not shifted.
    """
    check_switches(c_on_pF, c_off_pF)
    check_rank(m)
    capacitance = np.asarray(capacitance_pF, dtype=float)
    if capacitance.ndim not in (1, 2) or not np.isfinite(capacitance).all():
        raise ReadoutError(f"capacitances: expected finite (k,) or (poses, k), got shape {capacitance.shape}")
    rng = np.random.default_rng(noise.seed)
    k = m.array.k
    shape = (noise.runs,) + (1,) * (capacitance.ndim - 1) + (k,)
    shift = rng.uniform(-noise.relative_shift, noise.relative_shift, shape)
    truth = capacitance * (1 + shift)
    readings = ideal_readings(m, truth, c_on_pF, c_off_pF)
    readings += rng.uniform(-noise.additive_pF, noise.additive_pF, readings.shape)
    found = recover(m, readings)
    return ReadoutErrors(truth, found.capacitance_pF - truth, found.c_on_pF - c_on_pF, found.c_off_pF - c_off_pF)
