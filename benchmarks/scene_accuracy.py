"""Capacitance error of the forward simulation against wall time, per paper scene.

For each of the paper's scenes (jobs/poking, poking_cross, biaxial, pneumatic, joystick,
wrist and glove ``.toml``) every edge length is multiplied by a factor: ``[mesh]
edge_length_mm`` and ``edge_length_outline_mm``, ``[elastic] edge_length_mm`` (and its
``edge_length_outline_mm`` if set; unset, it follows as half the edge length). Grading
distances, layers through the thickness and the element orders stay the scene's. The
default factors are powers of √2, 2√2 to 1/2 (``FACTORS``); factor 1 is the scene as
shipped, marked ★. At factors √2 and 1 the other element orders run as well, one at a
time: electrostatics P1 ↔ P2 (``[mesh] order``) and elasticity P1 ↔ P2 (``[elastic]
order``, where a pose deforms), to show what a higher order buys.

Each level is the cold forward simulation (:func:`mscap.fem.simulate.simulate`: meshing,
every pose's elastic equilibrium, electrostatics) on one core in a process of its own,
so its peak resident memory (``ru_maxrss``) is its own; the wall time is that of
``simulate`` alone (the ~1–2 s of Python, PETSc and gmsh start-up are not counted).

Reference. The three finest levels at the scene's orders (factors f₁ > f₂ > f₃, a ratio
r = √(f₁/f₃) per level, √2 by default) give per pose and capacitor the observed order
p = log((C₁ − C₂)/(C₂ − C₃)) / log r and the Richardson value C* = C₃ + (C₃ − C₂)/(rᵖ − 1).
An entry whose differences change sign (not in the asymptotic range) takes C₃ instead;
p is clipped to [0.5, 4]; both count as flagged in the printed reference line. The
error of a level is max over poses and capacitors |C − C*| / |C*|. The default (factor
1) is one of the three levels, so its error is the extrapolated distance to C*, not an
independent check, and a small p inflates it (p = 0.6 puts C* 4.3 steps C₂ → C₃ beyond
C₃): ``error_vs_finest``, the same maximum against the finest level alone, is printed
beside it as a lower bound free of extrapolation. With fewer than three finished levels
the finest one is the reference. ``estimate`` is what a multi-start run stores
(:mod:`mscap.service.accuracy`, ``[multistart] error_estimate``): |C(f) − C(f/2)| / |C(f/2)| at
the same orders, where the level f/2 ran; for a rate p the error should be about
estimate · 2ᵖ/(2ᵖ − 1), and the two columns side by side show whether it is.

The signal. The objective and the k choice read differences of capacitances between
poses, not C: per level, ``signal_error`` is the worst relative error of a pose-to-pose
L1 distance ‖C_a − C_b‖₁ and ``metric_error`` that of the smallest one (the paper's
min-L1 metric), against the distances of the extrapolated C* (``_vs_finest`` against the
finest level, ``_estimate`` against the level at half the edges, as a run stores them).
Every finished level, its capacitance table included, is kept in
``docs/scene_accuracy_levels.json``; ``--reuse`` rebuilds the tables from it (or resumes
an interrupted run) without simulating again.

Cost, one idle core. From the default costs (poking 5.6 s, poking_cross ~6 s, biaxial
and pneumatic ~4 s, wrist 9.5 s, joystick 10.7 s, glove 22 s: ~62 s in all) and time ∝
tets^1.35 with tets ×3–4 per halving, the levels cost about 0.07, 0.17, 0.4, 1, 2.4 and
6× the default, ~10× in all, plus ~2 s start-up each: **~12 minutes for the six-factor
chains of all seven scenes**. The order variants at √2 and 1 add, from the smoke runs on
poking_quick (electrostatic P2 3.7× the P1 time at the same mesh, 620 MB against 205 MB
at 78k tets; elastic P2 with contact 13× P1 at √2, and docs/elastic.md's 18 s per poke
at 5 mm): electrostatic P2 ~5.5× the default per scene (~6 minutes for all seven),
elastic P2 ~1.5 minutes each on poking and poking_cross, and an extrapolated 1–3
minutes each on the glued and pneumatic scenes (biaxial's variant is P1, cheap): **a
full run of ~25–30 minutes, glove the longest at ~6–8 minutes**. A finer factor
1/(2√2) would cost ~15× the default (5.5 min on glove alone) and is left out; 2√2 costs
next to nothing and extends the curves to cheap, coarse settings. ``--max-seconds``
(default 120) stops a scene's chain of finer levels at the same orders once one level
took longer (by the estimates above no level should reach it; it bounds a surprise,
such as a P2 variant far slower than guessed); a level is killed after twice that and
counts as too slow. ``--no-variants`` halves the run.

Run (the full run on an otherwise idle machine; ``--quick`` is a 10-second smoke run on
jobs/poking_quick.toml, factors 2, √2, 1 and no order variants, into a temporary
directory)::

    .venv/bin/python benchmarks/scene_accuracy.py
    .venv/bin/python benchmarks/scene_accuracy.py --scenes glove wrist --factors 2,1.41,1,0.71,0.5
    .venv/bin/python benchmarks/scene_accuracy.py --quick

Writes ``docs/scene_accuracy.csv``, ``docs/scene_accuracy.png`` and the levels file
(``--csv``/``--png``/``--levels`` elsewhere) and prints a Markdown table per scene, the default's error and the cheapest
level within 1 %, the issue's default accuracy target.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):  # one core per level
    os.environ.setdefault(_var, "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import table_head, write_csv  # noqa: E402

SCENES = ("poking", "poking_cross", "biaxial", "pneumatic", "joystick", "wrist", "glove")
#: Edge-length factors, powers of √2 (2√2 … 1/2): Richardson over the three finest.
FACTORS = tuple(2.0 ** (k / 2) for k in (3, 2, 1, 0, -1, -2))
QUICK_FACTORS = (2.0, math.sqrt(2.0), 1.0)
#: Factors at which the other electrostatic and elastic orders run.
VARIANT_FACTORS = (math.sqrt(2.0), 1.0)
#: The issue's default accuracy target (relative capacitance error).
TARGET = 0.01
#: Bounds on the observed convergence order in the Richardson extrapolation.
P_RANGE = (0.5, 4.0)
FIELDS = ["scene", "factor", "electro_order", "elastic_order", "kind", "edge_length_outline_mm",
          "edge_length_mm", "elastic_edge_length_mm", "tets", "elastic_tets", "wall_s", "peak_rss_MB",
          "error", "error_vs_finest", "estimate", "signal_error", "signal_vs_finest", "signal_estimate",
          "metric_error", "metric_vs_finest", "metric_estimate"]
#: The columns a level's process measures.
MEASURED = FIELDS[5:12]


@dataclass(frozen=True)
class Level:
    """One run of a scene: edge-length ``factor`` and the two element orders."""

    factor: float
    electro_order: int
    elastic_order: int

    @property
    def orders(self) -> tuple[int, int]:
        return self.electro_order, self.elastic_order

    def label(self) -> str:
        return f"×{self.factor:.3g} P{self.electro_order}/P{self.elastic_order}"


def refined(scene, level: Level):
    """``scene`` with every edge length multiplied by ``level.factor`` and its orders."""
    mesh, elastic = scene.mesh, scene.elastic
    outline = elastic.edge_length_outline_mm
    f = level.factor
    return replace(scene,
                   mesh=replace(mesh, edge_length_mm=mesh.edge_length_mm * f,
                                edge_length_outline_mm=mesh.edge_length_outline_mm * f,
                                order=level.electro_order),
                   elastic=replace(elastic, edge_length_mm=elastic.edge_length_mm * f,
                                   edge_length_outline_mm=None if outline is None else outline * f,
                                   order=level.elastic_order))


def plan(scene, factors, variants: bool) -> tuple[Level, list[Level]]:
    """The scene's default level and every level to run, coarse to fine per orders."""
    default = Level(1.0, scene.mesh.order, scene.elastic.order)
    levels = [Level(f, *default.orders) for f in sorted(factors, reverse=True)]
    if variants:
        others = [(3 - default.electro_order, default.elastic_order)]
        if any(p.kind != "free" for p in scene.poses):
            others.append((default.electro_order, 3 - default.elastic_order))
        # the listed factor nearest √2 and 1 when one is within 2 % (1.41 for √2), so the
        # variants share the meshes of the scene's own levels
        at = [next((f for f in factors if math.isclose(f, v, rel_tol=0.02)), v) for v in VARIANT_FACTORS]
        levels += [Level(f, *orders) for orders in others for f in at]
    return default, levels


def measure(scene_path: str, level: Level) -> dict:
    """One level, in this process: the cold forward simulation of the refined scene."""
    import resource

    from mscap.fem.petsc import petsc, set_scene_options
    from mscap.scene import load_scene
    from mscap.fem.simulate import simulate

    petsc()
    scene = refined(load_scene(scene_path), level)
    set_scene_options(scene.petsc_options)
    t0 = time.perf_counter()
    sim = simulate(scene)
    wall = time.perf_counter() - t0
    return dict(tets=len(sim.mesh.tets), elastic_tets=0 if sim.elastic is None else len(sim.elastic.mesh.tets),
                capacitance_pF=sim.capacitance_pF.tolist(), poses=[p.name for p in sim.poses], wall_s=wall,
                peak_rss_MB=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                edge_length_outline_mm=scene.mesh.edge_length_outline_mm,
                edge_length_mm=scene.mesh.edge_length_mm, elastic_edge_length_mm=scene.elastic.edge_length_mm)


def run_level(scene_path: str, level: Level, timeout_s: float) -> dict | None:
    """One level in a fresh Python process; ``None`` if it failed or ran out of time."""
    child = f"{level.factor!r},{level.electro_order},{level.elastic_order}"
    try:
        out = subprocess.run([sys.executable, __file__, "--child", child, "--scenes", scene_path],
                             capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        print(f"  {level.label():<16} killed after {timeout_s:.0f} s", flush=True)
        return None
    if out.returncode != 0:
        print(f"  {level.label():<16} failed:\n{out.stderr[-2000:]}", flush=True)
        return None
    row = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"  {level.label():<16} {row['tets']:>9,d} tets {row['elastic_tets']:>7,d} elastic tets "
          f"{row['wall_s']:7.2f} s  peak {row['peak_rss_MB']:6.0f} MB", flush=True)
    return row


def richardson(c1, c2, c3, ratio: float):
    """Per entry, extrapolate from three levels refined by ``ratio`` each (coarse to fine).

    Returns the reference, the observed orders before clipping (NaN where the differences
    change sign and the finest value is taken) and a mask of those entries and of the ones
    whose order was clipped to ``P_RANGE``."""
    c1, c2, c3 = (np.asarray(c, dtype=float) for c in (c1, c2, c3))
    d12, d23 = c1 - c2, c2 - c3
    monotone = d12 * d23 > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        p_raw = np.where(monotone, np.log(np.abs(d12 / d23)) / np.log(ratio), np.nan)
    p = np.clip(np.nan_to_num(p_raw, nan=P_RANGE[0]), *P_RANGE)
    reference = np.where(monotone, c3 + (c3 - c2) / (ratio ** p - 1.0), c3)
    flagged = ~monotone | (p_raw < P_RANGE[0]) | (p_raw > P_RANGE[1])
    return reference, p_raw, flagged


def reference_of(levels, rows, default: Level):
    """Richardson reference from the three finest finished levels at the default orders,
    or the finest one when fewer finished; with a one-line description."""
    chain = sorted((lv for lv in levels if lv.orders == default.orders and rows.get(lv)),
                   key=lambda lv: -lv.factor)
    if not chain:
        return None, "no finished level at the default orders"
    if len(chain) < 3:
        finest = chain[-1]
        return np.array(rows[finest]["capacitance_pF"]), f"finest level only ({finest.label()}): no Richardson"
    a, b, c = chain[-3:]
    ratio = math.sqrt(a.factor / c.factor)
    reference, p, flagged = richardson(*(rows[lv]["capacitance_pF"] for lv in (a, b, c)), ratio)
    orders = (f"observed order median {np.nanmedian(p):.2f}, range {np.nanmin(p):.2f}–{np.nanmax(p):.2f}"
              if np.isfinite(p).any() else "no entry converges monotonically")
    poses = rows[c]["poses"]
    which = ", ".join(f"{poses[i]}/C{j} ({'non-monotone' if np.isnan(p[i, j]) else f'p {p[i, j]:.2f}'})"
                      for i, j in zip(*np.nonzero(flagged)))
    return reference, (f"Richardson over factors {a.factor:.3g}, {b.factor:.3g}, {c.factor:.3g} (ratio "
                       f"{ratio:.3g}): {orders}; {int(flagged.sum())} of {flagged.size} entries flagged "
                       f"(non-monotone: finest value taken; p clipped to {P_RANGE[0]:g}–{P_RANGE[1]:g})"
                       + (f": {which}" if which else ""))


def signal_errors(c, reference) -> tuple[float, float]:
    """The relative errors of what a design reads at capacitances ``c`` against
    ``reference`` (both ``(poses, k)``): the worst pose-to-pose L1 distance and the metric
    (the smallest one), as a multi-start run stores them (``RunRecord.signal_error``,
    ``metric_error``); NaN for a scene of one pose."""
    from mscap.design.history import pairwise_l1
    from mscap.service.accuracy import relative_difference

    if reference is None or len(c) < 2:
        return math.nan, math.nan
    d, d_ref = pairwise_l1(c), pairwise_l1(reference)
    return relative_difference(d, d_ref), float(abs(d.min() - d_ref.min()) / d_ref.min())


def scene_rows(name: str, levels, rows, default: Level, reference) -> list[dict]:
    """CSV rows of one scene: error against ``reference`` and the finer-mesh estimate, of
    the capacitances and of the pose-to-pose signal (:func:`signal_errors`; the reference
    signal is the one of the extrapolated capacitances)."""
    from mscap.service.accuracy import relative_difference

    finished = [lv for lv in levels if lv.orders == default.orders and rows.get(lv)]
    finest = np.array(rows[min(finished, key=lambda lv: lv.factor)]["capacitance_pF"]) if finished else None
    out = []
    for lv in levels:
        row = rows.get(lv)
        if row is None:
            continue
        c = np.array(row["capacitance_pF"])
        error = math.nan if reference is None else float(np.max(np.abs(c - reference) / np.abs(reference)))
        half = next((h for h in levels if h.orders == lv.orders and rows.get(h)
                     and math.isclose(h.factor, lv.factor / 2, rel_tol=0.02)), None)
        kind = "default" if lv == default else ("orders" if lv.orders != default.orders else "factor")
        finer = None if half is None else np.array(rows[half]["capacitance_pF"])
        signal = signal_errors(c, reference), signal_errors(c, finest), signal_errors(c, finer)
        out.append(dict(scene=name, factor=lv.factor, electro_order=lv.electro_order,
                        elastic_order=lv.elastic_order, kind=kind,
                        **{k: row[k] for k in MEASURED},
                        error=error, error_vs_finest=math.nan if finest is None else relative_difference(c, finest),
                        estimate=math.nan if finer is None else relative_difference(c, finer),
                        signal_error=signal[0][0], signal_vs_finest=signal[1][0], signal_estimate=signal[2][0],
                        metric_error=signal[0][1], metric_vs_finest=signal[1][1], metric_estimate=signal[2][1]))
    return out


def markdown(rows) -> str:
    """One scene's levels as a Markdown table."""
    head = ("| factor | electro/elastic | tets | elastic tets | wall s | peak MB | C error % | vs finest % "
            "| estimate % | signal error % | vs finest % | estimate % | metric error % | vs finest % |")
    lines = table_head(head)

    def pct(value):
        return "" if math.isnan(value) else f"{100 * value:.3f}"

    for r in rows:
        mark = " ★" if r["kind"] == "default" else ""
        lines.append(f"| {r['factor']:.3g}{mark} | P{r['electro_order']}/P{r['elastic_order']} | {r['tets']:,} "
                     f"| {r['elastic_tets']:,} | {r['wall_s']:.2f} | {r['peak_rss_MB']:.0f} "
                     f"| {pct(r['error'])} | {pct(r['error_vs_finest'])} | {pct(r['estimate'])} "
                     f"| {pct(r['signal_error'])} | {pct(r['signal_vs_finest'])} | {pct(r['signal_estimate'])} "
                     f"| {pct(r['metric_error'])} | {pct(r['metric_vs_finest'])} |")
    return "\n".join(lines)


def summary(rows) -> str:
    """The default's error and the cheapest level within the target."""
    default = next((r for r in rows if r["kind"] == "default"), None)
    within = [r for r in rows if r["error"] <= TARGET]
    cheapest = min(within, key=lambda r: r["wall_s"]) if within else None
    text = "default: not run" if default is None else (
        f"default ★ error {100 * default['error']:.3f} % (signal {100 * default['signal_error']:.3f} %, metric "
        f"{100 * default['metric_error']:.3f} %) in {default['wall_s']:.2f} s")
    text += "; nothing within 1 %" if cheapest is None else (
        f"; cheapest within 1 %: factor {cheapest['factor']:.3g}, P{cheapest['electro_order']}/"
        f"P{cheapest['elastic_order']}, {cheapest['wall_s']:.2f} s, error {100 * cheapest['error']:.3f} %")
    on_signal = [r for r in rows if r["signal_error"] <= TARGET]
    cheapest = min(on_signal, key=lambda r: r["wall_s"]) if on_signal else None
    text += "; nothing within 1 % on the signal" if cheapest is None else (
        f"; cheapest within 1 % on the signal: factor {cheapest['factor']:.3g}, P{cheapest['electro_order']}/"
        f"P{cheapest['elastic_order']}, {cheapest['wall_s']:.2f} s, signal error {100 * cheapest['signal_error']:.3f} %")
    return text


def plot(rows, names, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(names)
    cols = min(n, 4)
    fig, axes = plt.subplots(math.ceil(n / cols), cols, figsize=(4.2 * cols, 3.6 * math.ceil(n / cols)),
                             squeeze=False)
    for ax in axes.flat[n:]:
        ax.axis("off")
    for ax, name in zip(axes.flat, names):
        mine = [r for r in rows if r["scene"] == name]
        chain = sorted((r for r in mine if r["kind"] != "orders"), key=lambda r: r["wall_s"])

        def pts(sel, key="error"):
            return [r["wall_s"] for r in sel], [max(r[key], 1e-6) for r in sel]

        ax.loglog(*pts(chain), "o-", color="tab:blue", label="scene's orders, factors")
        if any(not math.isnan(r["signal_error"]) for r in chain):
            ax.loglog(*pts(chain, "signal_error"), "o:", mfc="none", color="tab:orange",
                      label="pose-to-pose signal, same levels")
        with_estimate = [r for r in chain if not math.isnan(r["estimate"])]
        if with_estimate:
            ax.loglog(*pts(with_estimate, "estimate"), "x", color="gray", label="finer-mesh estimate")
        default = [r for r in chain if r["kind"] == "default"]
        ax.loglog(*pts(default), "*", color="tab:red", ms=16, label="scene default")
        variants = [r for r in mine if r["kind"] == "orders"]
        for orders in sorted({(r["electro_order"], r["elastic_order"]) for r in variants}):
            sel = sorted((r for r in variants if (r["electro_order"], r["elastic_order"]) == orders),
                         key=lambda r: r["wall_s"])
            electro_changed = not chain or orders[0] != chain[0]["electro_order"]
            ax.loglog(*pts(sel), "s--" if electro_changed else "^--", mfc="none",
                      color="tab:green" if electro_changed else "tab:purple",
                      label=f"electro P{orders[0]} / elastic P{orders[1]}")
        for r in mine:
            ax.annotate(f"{r['factor']:.2g}", (r["wall_s"], max(r["error"], 1e-6)), fontsize=6,
                        xytext=(3, 3), textcoords="offset points")
        ax.axhline(TARGET, color="gray", ls=":", lw=1, label="1 % target")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("forward wall time, one core (s)", fontsize=8)
        ax.set_ylabel("max relative error (C; signal dotted)", fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


def _key(name: str, level: Level) -> str:
    return f"{name} {level.factor:.6g} {level.electro_order} {level.elastic_order}"


def load_levels(path: Path) -> dict:
    """The stored levels (key → a level's measured row with its capacitance table)."""
    return json.loads(path.read_text()) if path.exists() else {}


def run_scene(scene_path: str, factors, variants: bool, max_seconds: float, levels_path: Path | None = None,
              reuse: bool = False) -> list[dict]:
    """Every level of one scene (finer ones at the same orders skipped once a level took
    longer than ``max_seconds``), its reference, and its CSV rows. Each finished level
    (its capacitance table included) goes into ``levels_path``; with ``reuse`` a level
    found there is not run again (tables from stored levels, or a resumed run)."""
    from mscap.scene import load_scene

    name = Path(scene_path).stem
    default, levels = plan(load_scene(scene_path), factors, variants)
    print(f"{name}: {len(levels)} levels", flush=True)
    rows, slow = {}, {}
    stored = load_levels(levels_path) if levels_path is not None else {}
    for lv in levels:
        if reuse and _key(name, lv) in stored:  # a stored level counts however long it took
            rows[lv] = stored[_key(name, lv)]
            print(f"  {lv.label():<16} stored: {rows[lv]['wall_s']:7.2f} s", flush=True)
            continue
        if lv.factor < slow.get(lv.orders, 0.0):
            print(f"  {lv.label():<16} skipped: factor {slow[lv.orders]:.3g} took over {max_seconds:g} s", flush=True)
            continue
        rows[lv] = run_level(scene_path, lv, timeout_s=2 * max_seconds)
        if rows[lv] is not None and levels_path is not None:
            stored = load_levels(levels_path)
            stored[_key(name, lv)] = rows[lv]
            levels_path.write_text(json.dumps(stored, indent=0))
        if rows[lv] is None or rows[lv]["wall_s"] > max_seconds:
            slow[lv.orders] = lv.factor
    reference, how = reference_of(levels, rows, default)
    out = scene_rows(name, levels, rows, default, reference)
    print(f"\n### {name}\n\nreference: {how}\n\n{markdown(out)}\n\n{summary(out)}\n", flush=True)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", help="scene names in jobs/ or paths (default: the seven paper "
                        "scenes; --quick: poking_quick)")
    parser.add_argument("--factors", type=lambda s: tuple(map(float, s.split(","))),
                        help="comma-separated edge-length factors (default 2.83,2,1.41,1,0.71,0.5; "
                             "--quick: 2,1.41,1)")
    parser.add_argument("--variants", action=argparse.BooleanOptionalAction, default=None,
                        help="run the other element orders at factors 1.41 and 1 (default on; --quick: off)")
    parser.add_argument("--max-seconds", type=float, default=120.0,
                        help="skip finer levels at the same orders once a level took longer, and kill a "
                             "level after twice that (default 120)")
    parser.add_argument("--quick", action="store_true", help="smoke run: poking_quick, three levels, temp dir")
    parser.add_argument("--csv", help="CSV path (default docs/scene_accuracy.csv; --quick: a temporary directory)")
    parser.add_argument("--png", help="PNG path (default docs/scene_accuracy.png; --quick: a temporary directory)")
    parser.add_argument("--levels", help="JSON file of every finished level with its capacitances (default "
                        "docs/scene_accuracy_levels.json; --quick: a temporary directory)")
    parser.add_argument("--reuse", action="store_true",
                        help="take the levels found in --levels instead of running them again")
    parser.add_argument("--child", help=argparse.SUPPRESS)  # "factor,order,elastic_order": one level, JSON
    args = parser.parse_args(argv)
    names = args.scenes or (["poking_quick"] if args.quick else list(SCENES))
    paths = [n if n.endswith(".toml") else str(ROOT / "jobs" / f"{n}.toml") for n in names]
    if args.child is not None:
        factor, order, elastic_order = args.child.split(",")
        print(json.dumps(measure(paths[0], Level(float(factor), int(order), int(elastic_order)))))
        return

    out_dir = Path(tempfile.mkdtemp(prefix="mscap_scene_accuracy_")) if args.quick else ROOT / "docs"
    csv_path = Path(args.csv or out_dir / "scene_accuracy.csv")
    png_path = Path(args.png or out_dir / "scene_accuracy.png")
    levels_path = Path(args.levels or out_dir / "scene_accuracy_levels.json")
    factors = args.factors or (QUICK_FACTORS if args.quick else FACTORS)
    variants = (not args.quick) if args.variants is None else args.variants
    start = time.perf_counter()
    rows = []
    for path in paths:
        rows += run_scene(path, factors, variants, args.max_seconds, levels_path, args.reuse)
    write_csv(rows, csv_path, FIELDS)
    plot(rows, [Path(p).stem for p in paths], png_path)
    print("## Summary\n")
    for path in paths:
        name = Path(path).stem
        print(f"- {name}: {summary([r for r in rows if r['scene'] == name])}")
    print(f"\ntotal {time.perf_counter() - start:.0f} s; wrote {csv_path} and {png_path}")


if __name__ == "__main__":
    main()
