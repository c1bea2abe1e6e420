"""The figure of docs/validation.md for the paper's poking experiment: its numbers against
mscap's under each reading of the setup (``docs/paper_setups.csv``, the sweep of
``benchmarks/paper_setups.py``; ``docs/paper_identify.csv``, the fits of
``benchmarks/paper_identify.py``). Run after both::

    .venv/bin/python benchmarks/paper_figure.py

Writes ``docs/paper_poking.png``.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
NUMBERS = ("rest_pF", "pressed_pF", "along_x_pF", "along_y_pF", "diagonal_pF")
LABELS = ("rest", "pressed", "neighbour\nalong x", "neighbour\nalong y", "diagonal")
#: The paper's §4.4 (simulated: "approximately 57 pF", "around 9 pF", "1.3 pF each"; measured:
#: the mean of 59.7, 60.4, 53.4, 59.5 pF, "around 10.5 pF", "around 1.5 pF in all other").
PAPER = {"paper, simulated": (57.0, 9.0, 1.3, 1.3, 1.3), "paper, measured": (58.25, 10.5, 1.5, 1.5, 1.5)}


def rows(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


def main() -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sweep = rows(ROOT / "docs" / "paper_setups.csv")
    fits = rows(ROOT / "docs" / "paper_identify.csv")
    shipped = next(r for r in sweep if r["holding"] == "x" and float(r["radius_mm"]) == 10
                   and float(r["plate_mm"]) == 18 and float(r["applicator"]) == 0.7)
    bars = dict(PAPER)
    bars["mscap, x ends, 18 mm, 0.7 (shipped until 2026-12-06)"] = tuple(float(shipped[n]) for n in NUMBERS)
    for fit in fits:
        if fit["target"] in ("simulated", "measured_mean"):
            holding = "all edges" if fit["setup"].startswith("all") else "x ends"
            to = "the paper's simulation" if fit["target"] == "simulated" else "the measured means"
            label = f"mscap, {holding}, ball r {fit['setup'][-2:]} mm, fitted to {to}"
            bars[label] = tuple(float(fit[n]) for n in NUMBERS)
    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 4.6), gridspec_kw={"width_ratios": [1, 1.5]})
    x = np.arange(len(NUMBERS))
    width = 0.8 / len(bars)
    for i, (label, values) in enumerate(bars.items()):
        relative = np.array(values) / values[0] * 100
        relative[0] = values[0]
        left.bar(x[:1] + i * width, relative[:1], width, label=label)
        right.bar(x[1:] + i * width, relative[1:], width, label=label)
    left.set_xticks(x[:1] + 0.4 - width / 2, LABELS[:1])
    left.set_ylabel("rest capacitance (pF)")
    left.set_ylim(50, 62)
    left.set_title("each plate at rest")
    right.set_xticks(x[1:] + 0.4 - width / 2, LABELS[1:])
    right.set_ylabel("gain when poke_0 presses (% of rest)")
    right.set_title("a 1.3 cm poke over one plate")
    right.legend(fontsize=8, loc="upper right")
    fig.suptitle("Paper §4.4 poking sensor: which setup reproduces its numbers")
    fig.tight_layout()
    out = ROOT / "docs" / "paper_poking.png"
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
