"""An optimised design on its elastic mesh: outlines coarsened (the default) or embedded as they are.

A design's outlines pass through every outline vertex of the electrostatic mesh; the
elastic mesh embeds them coarsened to its own outline spacing
(``mscap.mesh.layered.elastic_layout``). This re-simulates one stored run's final outlines
both ways, at the scene's resolution and (``--finer``) at the finer-mesh check's, and
prints the elastic mesh size, the wall time and the largest relative capacitance
difference. Example (about 2 minutes on 2 cores)::

    .venv/bin/python benchmarks/elastic_outlines.py jobs/poking_cross.toml out/paper/poking_cross.h5 k6_s6014_random
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene")
    parser.add_argument("results", help="an mscap run results file")
    parser.add_argument("run", help="a run id in it, e.g. k6_s6014_random")
    parser.add_argument("--finer", action="store_true", help="at the finer-mesh check's resolution")
    args = parser.parse_args()
    import mscap.mesh.layered as layered
    from mscap.errors import MscapError
    from mscap.fem.simulate import simulate
    from mscap.geometry.layout import Layout
    from mscap.scene import load_scene
    from mscap.service.accuracy import finer
    from mscap.service.store import read_run, read_store

    try:
        scene = load_scene(args.scene)
        with read_store(args.results) as store:
            record = read_run(store, args.run)
    except (MscapError, KeyError) as exc:
        sys.exit(f"benchmarks/elastic_outlines.py: {exc}")
    sheet, elastic = replace(scene.sheet, layout=Layout(record.final_outlines)), scene.elastic
    if args.finer:
        sheet, elastic = finer(sheet, elastic)
    print(f"{args.run}: outline vertices {[len(o) for o in record.final_outlines]}")
    coarsened = layered.elastic_layout
    capacitance = {}
    for name, embed in (("coarsened", coarsened), ("as they are", lambda layout, *rest: layout)):
        layered.elastic_layout = embed
        start = time.perf_counter()
        sim = simulate(scene, keep_fields=False, sheet=sheet, elastic=elastic)
        capacitance[name] = sim.capacitance_pF
        print(f"{name:12s}: {len(sim.elastic.rest):6d} elastic nodes, simulation {time.perf_counter() - start:6.1f} s "
              f"(elastic {sim.times['elastic']:.1f} s)", flush=True)
    layered.elastic_layout = coarsened
    reference = capacitance["as they are"]
    print(f"max |C_coarsened - C| / C = {100 * np.max(np.abs(capacitance['coarsened'] - reference) / reference):.3f} %")


if __name__ == "__main__":
    main()
