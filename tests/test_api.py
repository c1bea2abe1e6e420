"""The package's front door: the public names of ``mscap``, and what importing costs."""

from __future__ import annotations

import copy
import inspect
import subprocess
import sys

import numpy as np
import pytest

import mscap
from tests.conftest import SMALL_SCENE, to_toml

#: Modules that need PETSc, MPI or the FEM stack: the store and ``mscap inspect`` load none.
HEAVY = ("petsc4py", "mpi4py", "gmsh", "scipy", "mscap.fem", "mscap.mesh", "mscap.design.pipeline",
         "mscap.design.optimizer", "mscap.bodies", "matplotlib")


def _loaded_after(statement: str) -> set[str]:
    code = f"import sys; {statement}; print('\\n'.join(sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    return set(out.split())


@pytest.mark.parametrize("statement", ["import mscap", "import mscap.service.store",
                                       "import mscap.service.selection", "import mscap.cli"])
def test_light_imports_load_no_fem_module(statement):
    loaded = _loaded_after(statement)
    heavy = sorted(m for m in loaded if m.startswith(HEAVY))
    assert not heavy, f"{statement} loads {heavy}"


def test_the_docstring_pipeline_runs(tmp_path):
    data = copy.deepcopy(SMALL_SCENE)
    data["poses"].append({"name": "pull", "kind": "stretch", "mode": "uniaxial", "stretch": 1.2, "grips": "clamp"})
    data["elastic"] = {"edge_length_mm": 5.0}
    path = tmp_path / "small.toml"
    path.write_text(to_toml(data))
    scene = mscap.load_scene(path)
    assert isinstance(scene, mscap.Scene)
    sim = mscap.simulate(scene)
    assert sim.capacitance_pF.shape == (len(scene.poses), scene.layout.k)
    design = mscap.build_design(scene)
    e = design.evaluate(design.deformer.zeros())
    np.testing.assert_allclose(e.capacitance_pF, sim.capacitance_pF, rtol=1e-9)
    assert design.gradient(e).shape == design.deformer.zeros().shape


def test_unknown_names_are_attribute_errors():
    with pytest.raises(AttributeError, match="no attribute 'simulation'"):
        mscap.simulation  # noqa: B018


PACKAGES = ("scene", "geometry", "mesh", "fem", "bodies", "design", "service", "calibration", "readout",
            "fabrication", "viz")


@pytest.mark.parametrize("package", PACKAGES)
def test_each_subpackage_offers_its_names_and_importing_it_costs_nothing(package):
    import importlib
    import pkgutil

    loaded = _loaded_after(f"import mscap.{package}")
    assert not [m for m in loaded if m.startswith(HEAVY) and m != f"mscap.{package}"]
    own = [m for m in loaded if m.startswith(f"mscap.{package}.")]
    assert package == "scene" or not own, own  # the scene loads its loader, as ever: it is light
    pkg = importlib.import_module(f"mscap.{package}")
    assert pkg.__all__ and pkg.__doc__.count("\n") >= 2
    # After every module of the package is loaded, a public name is still the object, not
    # a submodule of the same name (``mscap.fem.simulate`` is one).
    for info in pkgutil.iter_modules(pkg.__path__):
        importlib.import_module(f"mscap.{package}.{info.name}")
    for name in pkg.__all__:
        value = getattr(pkg, name)
        assert not inspect.ismodule(value), f"mscap.{package}.{name} is a module"
        if callable(value):
            assert name in importlib.import_module(value.__module__).__all__, \
                f"mscap.{package}.{name}: not public in {value.__module__}"
    with pytest.raises(AttributeError, match=f"'mscap.{package}' has no attribute 'nothing_here'"):
        pkg.nothing_here  # noqa: B018
