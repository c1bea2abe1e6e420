"""Scenes, meshes and helpers shared by tests of several packages (the small scene dicts
live in conftest.py)."""

from __future__ import annotations

import copy

import numpy as np
from scipy.optimize import brentq

from mscap.mesh.layered import extrude
from mscap.scene.settings import Layer, Material
from mscap.testing import taylor_test
from tests.conftest import SMALL_SCENE, grid_trimesh

# Paper §4.2 (as in SMALL_SCENE): the two silicones differ in E but share ν = 0.47.
CLEAR = Material("clear", 0.57, 0.47, 2.84)
CARBON = Material("carbon", 1.1, 0.47, 2.84)
KINDS = ("dielectric", "conductive", "dielectric", "conductive", "dielectric")
STACK_MM = (0.14, 0.07, 0.14, 0.07, 0.14)


#: jobs/quick.toml as issue 21 found it (P1 elastic elements of 5 mm), frozen here so that
#: the cases below keep their meaning when the shipped scene changes.
QUICK = """\
name = "quick"
description = "quick multi-start demo: two pokes and a stretch on a 40 x 30 mm sheet"

[sheet]
width_mm = 40.0
height_mm = 30.0

[materials.clear]
youngs_modulus_MPa = 0.57
poisson_ratio = 0.47
relative_permittivity = 2.84

[materials.carbon]
youngs_modulus_MPa = 1.1
poisson_ratio = 0.47
relative_permittivity = 2.84

[[layers]]
name = "protective_bottom"
kind = "dielectric"
thickness_mm = 0.14
material = "clear"

[[layers]]
name = "bottom_plates"
kind = "conductive"
thickness_mm = 0.07
material = "carbon"
fill = "clear"

[[layers]]
name = "dielectric"
kind = "dielectric"
thickness_mm = 0.14
material = "clear"

[[layers]]
name = "top_plates"
kind = "conductive"
thickness_mm = 0.07
material = "carbon"
fill = "clear"

[[layers]]
name = "protective_top"
kind = "dielectric"
thickness_mm = 0.14
material = "clear"

[capacitors]
min_gap_mm = 1.0
outlines_mm = [[[5.0, 8.0], [15.0, 8.0], [15.0, 20.0], [5.0, 20.0]],
               [[25.0, 8.0], [35.0, 8.0], [35.0, 20.0], [25.0, 20.0]]]

[mesh]
edge_length_mm = 4.0
edge_length_outline_mm = 0.5
grading_distance_mm = 2.0

[elastic]
edge_length_mm = 5.0
order = 1

[optimizer]
max_iterations = 15
cascade_levels = 0

[multistart]
k_min = 2
k_max = 4
starts_per_k = 4

[[poses]]
name = "poke_left"
kind = "poke"
center_mm = [12.0, 15.0]
radius_mm = 5.0
depth_mm = 3.0
held_edges = ["x_min", "x_max"]

[[poses]]
name = "poke_right"
kind = "poke"
center_mm = [28.0, 15.0]
radius_mm = 5.0
depth_mm = 3.0
held_edges = ["x_min", "x_max"]

[[poses]]
name = "stretch"
kind = "stretch"
mode = "uniaxial"
stretch = 1.2
grips = "roller"
"""


def stack(dielectric=CLEAR, plate=CARBON, fill=CLEAR):
    """The five layers: ``dielectric`` in layers 0, 2, 4; ``plate`` / ``fill`` in 1, 3."""
    return [Layer(f"layer{i}", kind, t, plate, fill) if kind == "conductive" else
            Layer(f"layer{i}", kind, t, dielectric) for i, (kind, t) in enumerate(zip(KINDS, STACK_MM))]


def grid_mesh(nx, ny, width, height, capacitor_of_centroid=None, jitter=0.25, seed=0):
    """A structured triangulation of ``width × height`` mm, interior vertices jittered by
    ``jitter`` cells, extruded with one element per layer. ``capacitor_of_centroid``
    defaults to one plate covering the whole sheet."""
    owner = capacitor_of_centroid or (lambda centroids: np.zeros(len(centroids)))
    return extrude(grid_trimesh(nx, ny, width, height, owner, jitter, seed), STACK_MM, 1)


def scene_dict(**changes):
    """SMALL_SCENE with some top-level entries replaced."""
    data = copy.deepcopy(SMALL_SCENE)
    data.update(copy.deepcopy(changes))
    return data


def strained(problem, seed=0):
    """A generic large strain: 30 % stretch, 20 % and 30 % compression, shear, plus node
    noise (smaller for P2, whose edge nodes are closer to their neighbours). Compression
    makes the tangent indefinite."""
    a = np.array([[1.3, 0.2, 0.05], [-0.1, 0.8, 0.1], [0.02, -0.05, 0.7]])
    noise = 0.01 if problem.order == 1 else 0.003
    return problem.rest @ a.T + np.random.default_rng(seed).normal(scale=noise, size=problem.rest.shape)


def free_thickness_stretch(l1, l2, material):
    """λ3 for which F = diag(λ1, λ2, λ3) has no normal stress P33.

    From P = μ (F − F⁻ᵀ) + λ ln J F⁻ᵀ: P33 = [μ (λ3² − 1) + λ ln(λ1 λ2 λ3)] / λ3, whose
    root depends on λ/μ = 2ν/(1 − 2ν) only."""
    mu, lam = material.lame_MPa
    return brentq(lambda l3: mu * (l3 ** 2 - 1) + lam * np.log(l1 * l2 * l3), 0.1, 10.0, xtol=1e-15)


def poke_scene_dict():
    """A 30 mm square sheet, one 10 mm capacitor in the middle, a 5 mm ball 3 mm deep."""
    return scene_dict(
        name="poke",
        sheet={"width_mm": 30.0, "height_mm": 30.0},
        capacitors={"min_gap_mm": 1.0, "outlines_mm": [[[10.0, 10.0], [20.0, 10.0], [20.0, 20.0], [10.0, 20.0]]]},
        mesh={"edge_length_mm": 3.0, "edge_length_outline_mm": 0.5, "grading_distance_mm": 2.0},
        # P1 as written when the cases that use it were measured (a poked scene without an
        # order gets P2 since 2026-12-05: tests/fem/test_elastic.py)
        elastic={"order": 1},
        poses=[{"name": "rest", "kind": "free"},
               {"name": "press", "kind": "poke", "center_mm": [15.0, 15.0], "radius_mm": 5.0,
                "depth_mm": 3.0, "held_edges": ["x_min", "x_max"]}])


def glue_scene(order):
    """A 20 × 10 mm sheet with one skewed plate glued onto a cylinder of radius 20 mm."""
    return scene_dict(
        name="glued", sheet={"width_mm": 20.0, "height_mm": 10.0},
        capacitors={"min_gap_mm": 1.0, "outlines_mm": [[[4.0, 2.0], [13.0, 2.5], [14.0, 7.5], [5.0, 8.0]]]},
        mesh={"edge_length_mm": 3.0, "edge_length_outline_mm": 1.0, "grading_distance_mm": 2.0},
        objects={"arm": {"generator": "cylinder", "width_mm": 30.0, "height_mm": 20.0,
                         "corner_mm": [-5.0, -5.0], "edge_length_mm": 1.0}},
        poses=[{"name": "bent", "kind": "glue", "object": "arm", "radius_mm": 20.0}],
        elastic={"edge_length_mm": 4.0, "order": order})


def flat(outlines):
    return np.concatenate([np.ravel(o) for o in outlines])


def unflat(vector, like):
    sizes = np.cumsum([np.size(o) for o in like])[:-1]
    return [v.reshape(np.shape(o)) for v, o in zip(np.split(vector, sizes), like)]


def check_gradient(term, x, rng, h0, geometric=True):
    """Taylor rates over four halvings and the central-difference relative error."""
    wrap = (lambda v: unflat(v, x)) if geometric else (lambda v: v.reshape(np.shape(x)))
    x0 = flat(x) if geometric else np.ravel(x)
    value, grad = term.value_and_gradient(wrap(x0))
    grad = flat(grad) if geometric else np.ravel(grad)
    result = taylor_test(lambda v: term.value(wrap(v)), x0, rng.standard_normal(x0.size), grad,
                         value=value, h0=h0, halvings=4, central_step=1e-3 * h0)
    return result.rates, result.central_error
