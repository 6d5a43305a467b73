"""Densities by label, objects.json's physical keys, and the provenance in scene.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from helpers_state import StateObj, pose, write_init_state
from r2s.errors import InputError
from r2s.io.input_scene import load_objects
from r2s.io.paths import ScenePaths
from r2s.physical.density_table import (DEFAULT_DENSITY_KG_M3, TABLE, YCB_MASS_KG,
                                        density_for_label)
from r2s.physical.provenance import com_provenance, friction_provenance, nominal_mass
from r2s.runner.base import run_stage
from r2s.stages.export import STAGE as EXPORT, Options as ExportOptions


def test_labels_find_their_category_and_unknown_labels_the_default():
    assert density_for_label("003_cracker_box").category == "box"
    assert density_for_label("005_tomato_soup_can").category == "can"
    assert density_for_label("Coffee Mug").category == "mug"
    assert density_for_label("013_apple").category == "fruit"
    unknown = density_for_label("038_padlock")
    assert unknown.source == "default_density"
    assert unknown.density_kg_m3 == DEFAULT_DENSITY_KG_M3
    assert all(e.ref for e in TABLE)


@pytest.mark.parametrize("category, members", [
    ("box", ["003_cracker_box", "004_sugar_box", "008_pudding_box", "009_gelatin_box"]),
    ("can", ["002_master_chef_can", "005_tomato_soup_can", "007_tuna_fish_can",
             "010_potted_meat_can"]),
])
def test_ycb_derived_densities_recompute_from_published_masses(category, members):
    """The table's value is the median of published mass / closed mesh volume."""
    from r2s.synth.catalog import load_object_mesh

    rho = [YCB_MASS_KG[m] / load_object_mesh(m).volume for m in members]
    entry = next(e for e in TABLE if e.category == category)
    assert entry.density_kg_m3 == pytest.approx(float(np.median(rho)), rel=0.01)


def test_nominal_mass_prefers_user_values_then_the_table():
    volume = 1e-3  # one litre
    assert nominal_mass("003_cracker_box", volume)[0] == pytest.approx(0.554)
    entry = type("E", (), {"mass_kg": 0.41, "density_kg_m3": None})()
    mass, prov = nominal_mass("003_cracker_box", volume, entry)
    assert mass == 0.41 and prov["source"] == "user"
    entry = type("E", (), {"mass_kg": None, "density_kg_m3": 200.0})()
    mass, prov = nominal_mass("003_cracker_box", volume, entry)
    assert mass == pytest.approx(0.2) and prov == {"source": "user_density",
                                                   "density_kg_m3": 200.0}
    mass, prov = nominal_mass("thing", volume)
    assert mass == pytest.approx(0.6) and prov["source"] == "default_density"


def test_friction_and_com_sources():
    assert friction_provenance(1.0, bounds=(0.2, 1.0), initial=0.6,
                               raised_for_stability=True)["source"] == "at_bound"
    assert friction_provenance(0.6, bounds=(0.2, 1.0), initial=0.6)["source"] == "default"
    assert friction_provenance(0.73, bounds=(0.2, 1.0), initial=0.6)["source"] == "optimised"
    assert friction_provenance(0.5, user=0.5, bounds=(0.2, 1.0))["source"] == "user"
    com = com_provenance(np.array([0.0, 0.0, -0.016]), np.zeros(3))
    assert com["source"] == "repaired" and com["shift_m"] == pytest.approx(0.016)
    assert com_provenance(np.zeros(3), np.zeros(3))["source"] == "mesh_centroid"


def _objects_json(scene: Path, entries: list[dict]) -> None:
    (scene / "input").mkdir(parents=True, exist_ok=True)
    (scene / "input" / "objects.json").write_text(json.dumps({"objects": entries}))


def test_objects_json_rejects_a_non_positive_mass(tmp_path: Path):
    _objects_json(tmp_path, [{"id": 1, "mass_kg": -0.2}])
    with pytest.raises(InputError, match="mass_kg"):
        load_objects(ScenePaths(tmp_path))


def test_export_uses_objects_json_and_the_table_and_says_so(tmp_path: Path):
    """Box 1: user mass and friction; box 2 (a 'can'): the table's density x volume;
    box 3: unknown label, the default density; its COM is moved 16 mm (a repair)."""
    cube = trimesh.creation.box([0.1, 0.1, 0.1])   # 1e-3 m^3
    objs = [StateObj(1, cube, pose([0, 0, 0.05]), label="cracker box", mass_kg=None,
                     friction=None),
            StateObj(2, cube, pose([0.3, 0, 0.05]), label="soup can", mass_kg=None,
                     friction=None),
            StateObj(3, cube, pose([0.6, 0, 0.05]), label="gizmo", mass_kg=None,
                     friction=None, com_in_object=[0.0, 0.0, -0.016])]
    write_init_state(tmp_path, objs)
    _objects_json(tmp_path, [{"id": 1, "mass_kg": 0.41, "friction": 0.45}])
    run_stage(EXPORT, tmp_path, ExportOptions(source="init", default_friction=0.8,
                                              observation=False))  # input/ has no image
    scene = json.loads((tmp_path / "export" / "scene.json").read_text())
    by_id = {o["id"]: o for o in scene["objects"]}
    assert by_id[1]["mass_kg"] == pytest.approx(0.41)
    assert by_id[1]["friction"] == pytest.approx(0.45)
    assert by_id[1]["provenance"]["mass"]["source"] == "user"
    assert by_id[1]["provenance"]["friction"]["source"] == "user"
    assert by_id[2]["mass_kg"] == pytest.approx(1.069, rel=1e-6)
    assert by_id[2]["provenance"]["mass"]["category"] == "can"
    assert by_id[2]["provenance"]["friction"] == {"source": "default", "value": 0.8}
    assert by_id[3]["mass_kg"] == pytest.approx(0.6, rel=1e-6)
    assert by_id[3]["provenance"]["mass"]["source"] == "default_density"
    assert by_id[3]["provenance"]["com"]["source"] == "repaired"
    assert by_id[3]["provenance"]["com"]["shift_m"] == pytest.approx(0.016, abs=1e-9)
    assert by_id[1]["provenance"]["com"]["source"] == "mesh_centroid"
    # the inertia follows the mass: a uniform cube, m a^2 / 6
    assert np.allclose(np.diag(by_id[1]["inertia_about_com"]), 0.41 * 0.01 / 6, rtol=1e-6)
