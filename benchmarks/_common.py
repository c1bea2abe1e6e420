"""Helpers shared by the benchmark scripts (imported as ``benchmarks._common``)."""

from __future__ import annotations

import csv
from pathlib import Path


def write_csv(rows, path: Path, fields) -> None:
    """``rows`` (dicts) as CSV with the columns ``fields``; floats to 6 significant digits."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})


def tolerance_text(path: Path, tolerance: float = 0.01) -> str:
    """A scene file's text with its three hand-set ``[mesh]`` sizes (or its own tolerance)
    replaced by ``tolerance = …`` (the mesh the size ladder picks, with zones under the
    balls)."""
    lines, table = [], ""
    for line in Path(path).read_text().splitlines():
        if line.startswith("["):
            table = line.strip()
        if table == "[mesh]" and line.split("=")[0].strip() in ("edge_length_mm", "edge_length_outline_mm",
                                                                 "grading_distance_mm", "tolerance"):
            continue
        lines.append(line)
        if line.strip() == "[mesh]":
            lines.append(f"tolerance = {tolerance!r}")
    return "\n".join(lines) + "\n"


def table_head(head: str) -> list[str]:
    """A Markdown table's header line and its rule."""
    return [head, "|" + "---|" * (head.count("|") - 1)]
