"""Open containers among completed shapes: found from the top surface's basin, weighed by
their walls (r2s/geometry/open_container.py), and used for a completion's mass in physopt
and, where physopt did not run, in export."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from helpers_state import StateObj, pose, write_init_state
from r2s.geometry.open_container import AREAL_DENSITY_KG_M2, open_container
from r2s.io.state import ObjectState, SceneState, SupportPlane
from r2s.physical.provenance import container_mass
from r2s.physopt.params import initial_params
from r2s.runner.base import run_stage
from r2s.stages.export import STAGE as EXPORT, Options as ExportOptions


def _revolved(profile_rz: list[tuple[float, float]]) -> trimesh.Trimesh:
    """A closed solid of revolution about z from its (radius, height) outline."""
    return trimesh.creation.revolve(np.asarray(profile_rz, dtype=float), sections=96)


def _cup(radius_m: float, height_m: float, wall_m: float, floor_m: float) -> trimesh.Trimesh:
    """A cup standing on z = 0: outer radius and height, a wall ``wall_m`` thick, its
    inside down to ``floor_m`` (a completion fills the space under what it saw of the dip:
    a high floor)."""
    r, h, t = radius_m, height_m, wall_m
    return _revolved([(0, 0), (r, 0), (r, h), (r - t, h), (r - t, floor_m), (0, floor_m)])


def _outside_area_m2(radius_m: float, height_m: float) -> float:
    """Bottom and side of a cylinder: what a cup's walls cover, without the opening."""
    return np.pi * radius_m**2 + 2 * np.pi * radius_m * height_m


@pytest.mark.parametrize("floor_m", [0.002, 0.03, 0.05])
def test_a_cup_is_a_container_whose_walls_cover_its_outside(floor_m):
    cup = _cup(0.04, 0.08, 0.002, floor_m)
    found = open_container(cup)
    assert found is not None
    assert found.depth_m == pytest.approx(0.08 - floor_m, abs=2e-3)
    assert found.footprint_area_m2 == pytest.approx(np.pi * 0.04**2, rel=0.05)
    # the outside only: the inner wall and the floor of the dip are the other side of the
    # same walls
    assert found.shell_area_m2 == pytest.approx(_outside_area_m2(0.04, 0.08), rel=0.05)
    assert found.walls_mass_kg() == pytest.approx(
        AREAL_DENSITY_KG_M2 * _outside_area_m2(0.04, 0.08), rel=0.05)


def test_a_bowl_is_a_container():
    bowl = _revolved([(0, 0), (0.05, 0), (0.08, 0.055), (0.078, 0.055), (0.048, 0.01),
                      (0, 0.01)])
    found = open_container(bowl)
    assert found is not None
    assert found.depth_m == pytest.approx(0.045, abs=2e-3)
    # outside: the foot (radius 50 mm) and the flared side (a frustum 50 -> 80 mm, 55 high)
    frustum = np.pi * (0.05 + 0.08) * np.hypot(0.03, 0.055)
    assert found.shell_area_m2 == pytest.approx(np.pi * 0.05**2 + frustum, rel=0.05)


def test_shapes_without_a_basin_are_not_containers():
    box = trimesh.creation.box([0.10, 0.06, 0.04])
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
    upside_down = _cup(0.04, 0.08, 0.002, 0.002)
    upside_down.apply_transform(trimesh.transformations.rotation_matrix(np.pi, [1, 0, 0]))
    # an L: the dip between its arms is open on three sides, water runs off
    shift = trimesh.transformations.translation_matrix
    ell = trimesh.util.concatenate([
        trimesh.creation.box([0.10, 0.06, 0.02], transform=shift([0, 0, 0.01])),
        trimesh.creation.box([0.02, 0.06, 0.06], transform=shift([0.04, 0, 0.03]))])
    for shape in (box, ball, upside_down, ell):
        assert open_container(shape) is None


def test_a_shallow_or_small_dip_does_not_make_a_container():
    shallow = _cup(0.04, 0.08, 0.002, 0.075)          # 5 mm dip: a dent, not a cup
    narrow = _cup(0.04, 0.08, 0.025, 0.02)            # a deep hole over 14 % of the top
    assert open_container(shallow) is None
    assert open_container(narrow) is None


def _state(source: str) -> SceneState:
    obj = ObjectState(id=1, label="", mesh="meshes/1.glb", world_from_object=np.eye(4).tolist(),
                      source=source)
    return SceneState(stage="geomopt", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                      objects=[obj])


@pytest.mark.parametrize("source, hollow", [("completed", True), ("prior", False)])
def test_physopt_weighs_a_completed_container_by_its_walls(source, hollow):
    # a completion of a cup seen from above: solid under the 30 mm of dip it saw, 266 cm^3:
    # 0.16 kg at the default 600 kg/m^3; its walls, 4.35 kg/m^2 over 251 cm^2, 0.11 kg
    cup = _cup(0.04, 0.08, 0.002, 0.05)
    params = initial_params(_state(source), {1: cup}, {1: [cup.convex_hull]}, None,
                            (0.5, 2.0), 0.6)
    p = params[1]
    if hollow:
        walls_kg = AREAL_DENSITY_KG_M2 * _outside_area_m2(0.04, 0.08)
        assert p.nominal_mass_kg == pytest.approx(walls_kg, rel=0.05)
        assert p.mass_kg == pytest.approx(p.nominal_mass_kg)
        assert p.mass_provenance["source"] == "open_container"
        assert p.mass_provenance["solid"]["source"] == "default_density"
    else:  # a prior's mesh is its shape as given
        assert p.nominal_mass_kg == pytest.approx(600.0 * float(cup.volume), rel=1e-6)
        assert p.mass_provenance["source"] == "default_density"


def test_a_density_forced_by_the_stage_option_is_kept_for_a_container():
    # 2000 kg/m^3 x 266 cm^3 is 0.53 kg, five times the walls' 0.11 kg: kept all the same
    cup = _cup(0.04, 0.08, 0.002, 0.05)
    params = initial_params(_state("completed"), {1: cup}, {1: [cup.convex_hull]}, 2000.0,
                            (0.5, 2.0), 0.6)
    assert params[1].nominal_mass_kg == pytest.approx(2000.0 * float(cup.volume), rel=1e-6)
    assert params[1].mass_provenance["source"] == "default_density"


def test_export_without_physopt_weighs_a_completed_container_by_its_walls(tmp_path: Path):
    # the same cup twice: as a completion (walls) and as a prior (its mesh's volume)
    cup = _cup(0.04, 0.08, 0.002, 0.05)
    write_init_state(tmp_path, [
        StateObj(1, cup, pose([0, 0, 0]), label="", mass_kg=None, source="completed"),
        StateObj(2, cup, pose([0.2, 0, 0]), label="", mass_kg=None, source="prior")])
    run_stage(EXPORT, tmp_path, ExportOptions(source="init", observation=False))
    scene = json.loads((tmp_path / "export" / "scene.json").read_text())
    by_id = {o["id"]: o for o in scene["objects"]}
    walls_kg = AREAL_DENSITY_KG_M2 * _outside_area_m2(0.04, 0.08)
    assert by_id[1]["mass_kg"] == pytest.approx(walls_kg, rel=0.05)
    assert by_id[1]["provenance"]["mass"]["source"] == "open_container"
    assert by_id[2]["mass_kg"] == pytest.approx(600.0 * float(cup.volume), rel=0.01)
    assert by_id[2]["provenance"]["mass"]["source"] == "default_density"


def test_walls_heavier_than_the_solid_leave_the_solid_and_its_record():
    # a cup completed almost empty of its inside (a 15 mm floor under a 65 mm dip, 40 mm
    # wide): 0.5 x 600 kg/m^3 of solid is lighter than its walls at 4.35 kg/m^2
    cup = _cup(0.02, 0.08, 0.002, 0.015)
    found = open_container(cup)
    assert found is not None
    solid_kg = 600.0 * float(cup.volume)
    assert found.walls_mass_kg() > 0.5 * solid_kg
    mass, prov = container_mass(lambda: found, 0.5 * solid_kg, {"source": "default_density"})
    assert mass == pytest.approx(0.5 * solid_kg)
    assert prov == {"source": "default_density"}
    mass, prov = container_mass(lambda: found, 10 * solid_kg, {"source": "default_density"})
    assert mass == pytest.approx(found.walls_mass_kg())
    assert prov["source"] == "open_container"
