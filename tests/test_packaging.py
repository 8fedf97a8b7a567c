"""The package's build configuration ships every subpackage and the built-in vehicle profiles."""

from __future__ import annotations

from pathlib import Path

import pytest

import o3d_terrain
from o3d_terrain import traversability

ROOT = Path(o3d_terrain.__file__).resolve().parents[1]


def _setuptools_config() -> dict:
    tomllib = pytest.importorskip("tomllib", reason="tomllib needs Python 3.11")
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_every_subpackage_is_listed_for_the_wheel():
    listed = set(_setuptools_config()["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts)
             for p in (ROOT / "o3d_terrain").rglob("__init__.py")}
    assert found - listed == set(), "add these packages to [tool.setuptools] packages"


def test_vehicle_profiles_ship_inside_the_package():
    config = _setuptools_config()
    source = config["package-dir"]["o3d_terrain.vehicles"]
    assert (ROOT / source).resolve() == (ROOT / "configs" / "vehicles").resolve()
    assert "o3d_terrain.vehicles" in config["packages"]
    assert config["package-data"]["o3d_terrain.vehicles"] == ["*.yaml"]
    # in a source checkout the profiles are read from configs/vehicles
    assert traversability.VEHICLES_DIR == ROOT / "configs" / "vehicles"
    assert set(traversability.vehicle_profile_names()) == {
        p.stem for p in (ROOT / "configs" / "vehicles").glob("*.yaml")}


def test_top_level_names_resolve_and_the_module_example_runs():
    """Every name in ``o3d_terrain.__all__`` exists, and the drop-in calls of the package
    docstring chain on a synthetic scene: terrain, obstacles above it, a cost map."""
    for name in o3d_terrain.__all__:
        assert hasattr(o3d_terrain, name), name
    from o3d_terrain.synthetic import make_scene, sample_lidar

    scene = make_scene("crossing", seed=0)
    cloud = sample_lidar(scene, seed=0)
    surface, inliers = o3d_terrain.segment_terrain(cloud.positions)
    obstacles = o3d_terrain.detect_obstacles(cloud.positions, surface=surface)
    costmap = o3d_terrain.traversability_cost(surface, cloud.positions, vehicle="offroad_suv")
    assert 0 < len(inliers) < len(cloud.positions)
    assert len(obstacles) > 0 and all(len(o.indices) > 0 for o in obstacles)
    assert isinstance(costmap, o3d_terrain.CostMap)
