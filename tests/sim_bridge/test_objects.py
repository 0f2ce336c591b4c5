"""Objects for the grasp simulation: mass properties, loaders, clear errors."""

import pathlib

import numpy as np
import pytest
import trimesh

from sim_bridge.physics import hand_model
from sim_bridge.physics.objects import ObjectError, load_mesh_object, parse_object_arg, procedural_object, random_procedural_objects

pytestmark = pytest.mark.drake

# ../shared/meshes beside the repository (tests that need it skip without it)
VGN = pathlib.Path(__file__).resolve().parents[3] / "shared" / "meshes" / "vgn_train"


def test_box_mass_properties_match_the_formula():
    box = procedural_object("box", (0.04, 0.06, 0.1), mass_kg=0.6)
    m, (a, b, c) = 0.6, (0.04, 0.06, 0.1)
    np.testing.assert_allclose(np.diag(box.inertia_kg_m2),
                               [m * (b * b + c * c) / 12, m * (a * a + c * c) / 12, m * (a * a + b * b) / 12],
                               rtol=1e-6)
    np.testing.assert_allclose(box.com_m, 0, atol=1e-9)
    assert box.collision_mesh().extents == pytest.approx([0.04, 0.06, 0.1])


def test_density_gives_mass_and_overrides_scale_inertia():
    cyl = procedural_object("cylinder", (0.065, 0.2), density_kg_m3=500)
    assert cyl.mass_kg == pytest.approx(500 * np.pi * 0.0325 ** 2 * 0.2, rel=0.01)
    heavy = cyl.with_mass(2 * cyl.mass_kg)
    np.testing.assert_allclose(heavy.inertia_kg_m2, 2 * cyl.inertia_kg_m2)
    handle = procedural_object("box_with_handle", (0.06, 0.06, 0.1), mass_kg=0.3)
    assert len(handle.parts) == 4 and handle.com_m[0] > 0.001  # the handle shifts the COM to +x
    assert parse_object_arg("cylinder:0.065x0.2", mass_kg=0.5).mass_kg == 0.5


@pytest.mark.parametrize("kind,dims,mass,msg", [
    ("box", (0.04, 0.05, 0.06), 0.0, "not positive"),
    ("box", (0.04, 0.05), 0.1, "must be 3 positive"),
    ("cone", (0.04,), 0.1, "unknown object kind"),
    ("capsule", (0.05, 0.03), 0.1, "shorter than its diameter"),
])
def test_bad_procedural_objects_say_why(kind, dims, mass, msg):
    with pytest.raises(ObjectError, match=msg):
        procedural_object(kind, dims, mass_kg=mass)


def test_bad_mesh_files_say_why(tmp_path):
    flat = tmp_path / "flat.obj"
    flat.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n")
    with pytest.raises(ObjectError, match="zero volume"):
        load_mesh_object(flat, mass_kg=0.1)
    junk = tmp_path / "junk.obj"
    junk.write_bytes(b"\x00\x01 not a mesh")
    with pytest.raises(ObjectError, match="junk.obj"):
        load_mesh_object(junk, mass_kg=0.1)
    with pytest.raises(ObjectError, match="not found"):
        load_mesh_object(tmp_path / "missing.urdf")
    good = tmp_path / "cube.obj"
    trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(good)
    with pytest.raises(ObjectError, match="mass_kg or density"):
        load_mesh_object(good)
    assert load_mesh_object(good, density_kg_m3=1000).mass_kg == pytest.approx(0.125)
    nomass = tmp_path / "nomass.urdf"
    nomass.write_text('<robot name="x"><link name="l"><collision><geometry><mesh filename="cube.obj"/>'
                      "</geometry></collision></link></robot>")
    with pytest.raises(ObjectError, match="no <inertial><mass>"):
        load_mesh_object(nomass)


@pytest.mark.skipif(not VGN.is_dir(), reason="shared VGN meshes not present")
def test_vgn_urdf_loads_with_its_mass_and_convex_pieces():
    urdf = sorted(VGN.glob("*.urdf"))[0]
    obj = load_mesh_object(urdf)
    assert obj.mass_kg == pytest.approx(float(urdf.read_text().split('mass value="')[1].split('"')[0]))
    assert len(obj.parts) >= 1 and all(p.kind == "convex" for p in obj.parts)
    assert np.all(np.linalg.eigvalsh(obj.inertia_kg_m2) > 0)
    # URDF inertias (1 kg m² placeholders) are ignored: real ones are tiny
    assert np.max(obj.inertia_kg_m2) < 0.01
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder
    plant, _ = AddMultibodyPlantSceneGraph(DiagramBuilder(), 0.002)
    body = obj.add_to_plant(plant, mass_kg=0.2)
    plant.Finalize()
    assert plant.CalcTotalMass(plant.CreateDefaultContext(), [body.model_instance()]) == pytest.approx(0.2)
    assert len(plant.GetCollisionGeometriesForBody(body)) == len(obj.parts)  # paper contact by default


def test_random_objects_are_reproducible_and_mostly_graspable():
    a = random_procedural_objects(30, seed=3)
    b = random_procedural_objects(30, seed=3)
    assert [o.name for o in a] == [o.name for o in b]
    assert all(np.allclose(x.inertia_kg_m2, y.inertia_kg_m2) for x, y in zip(a, b))
    assert all(0.03 <= o.mass_kg <= 1.5 for o in a)
    fits = [min(o.collision_mesh().extents) < hand_model.MAX_STROKE_M for o in a]
    assert sum(fits) >= 0.8 * len(a)


def test_short_box_with_handle_has_positive_parts():
    # a 30 mm tall box once gave its handle a negative bar length (Drake aborts on those)
    obj = procedural_object("box_with_handle", (0.05, 0.05, 0.03), mass_kg=0.2)
    assert all(min(p.size) > 0 for p in obj.parts)
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder
    plant, _ = AddMultibodyPlantSceneGraph(DiagramBuilder(), 0.002)
    obj.add_to_plant(plant)
    for seed in range(5):
        for o in random_procedural_objects(20, seed):
            assert all(min(p.size) > 0 for p in o.parts if p.kind != "convex"), o.name
