"""Reports of a forward simulation: the pose × capacitor table of ``mscap simulate`` and
its JSON record."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mscap.fem.simulate import Simulation

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["simulation_record", "simulation_text"]


def _iterations(sim: Simulation) -> list[int]:
    return [r.state.newton_iterations if r.state else 0 for r in sim.poses]


def simulation_record(scene: Scene, sim: Simulation, files=()) -> dict:
    """One JSON-ready record: capacitances (pF), Newton iterations, load steps, times (s)."""
    record = {"scene": scene.name, "poses": [r.name for r in sim.poses],
              "capacitance_pF": sim.capacitance_pF.tolist(), "newton_iterations": _iterations(sim),
              "load_steps": [r.state.load_steps if r.state else 0 for r in sim.poses],
              "time_s": {key: sim.times[key] for key in ("mesh", "elastic", "electrostatic", "total")},
              "elastic_split_s": sim.times["elastic_split"]}
    if files:
        record["files"] = [str(f) for f in files]
    return record


def simulation_text(scene: Scene, sim: Simulation) -> str:
    """The mesh, a pose × capacitor table (pF) with Newton iterations, load steps and
    times per pose, and the time per stage."""
    k = sim.electro.k
    lines = [f"scene {scene.name} ({scene.path}): {len(sim.poses)} poses, {k} capacitors, "
             f"{len(sim.mesh.points)} vertices, {len(sim.mesh.tets)} tets"]
    if sim.elastic is not None:
        where = "the electrostatic mesh" if sim.transfer is None else (
            f"its own mesh of {len(sim.elastic.mesh.tets)} tets, {len(sim.elastic.mesh.level_z_mm) - 1} "
            f"through the stack")
        lines.append(f"  elastic: P{sim.elastic.order}, {sim.elastic.n_dofs} dofs on {where}")
    header = "".join(f"{'C' + str(j) + '_pF':>10}" for j in range(k))
    lines.append(f"  {'pose':<16}{header} {'newton':>7} {'steps':>6} {'elastic_s':>10} {'electro_s':>10}")
    for r, iterations in zip(sim.poses, _iterations(sim)):
        caps = "".join(f"{c:>10.3f}" for c in r.capacitance_pF)
        steps = r.state.load_steps if r.state else 0
        lines.append(f"  {r.name:<16}{caps} {iterations:>7d} {steps:>6d} "
                     f"{r.elastic_s:>10.2f} {r.electrostatic_s:>10.2f}")
    t = sim.times
    lines.append(f"  time: mesh {t['mesh']:.2f} s, setup {t['setup']:.2f} s, elastic {t['elastic']:.2f} s, "
                 f"electrostatic {t['electrostatic']:.2f} s, total {t['total']:.2f} s")
    if sim.elastic is not None:
        lines.append("  elastic: " + ", ".join(f"{key.replace('_', ' ')} {value:.2f} s"
                                               for key, value in t["elastic_split"].items()))
    return "\n".join(lines)
