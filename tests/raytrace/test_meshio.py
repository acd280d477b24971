"""User-mesh loader: formats, parts and transforms, repair counts, errors, real NASA meshes.

Oracles: synthetic files whose defects are planted by hand (the removed counts must equal
the planted numbers), transforms recomputed independently with NumPy, and for the NASA
meshes (NASA 3D Resources models re-exported as geometry-only GLB, not in the repository: set
ORBITSYNTH_TEST_MODELS to a folder holding them, else those tests skip) an independent NumPy count on the raw trimesh load plus the defect counts measured on those
files with trimesh.
"""

import dataclasses
import os
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings, strategies as st
from numpy.testing import assert_allclose
from trimesh.visual import TextureVisuals
from trimesh.visual.material import PBRMaterial

from raytrace.meshio import DEGENERATE_AREA_M2, MeshReport, component_summary, load_mesh
from raytrace.model import MATERIALS, SEMANTIC_CLASSES

MODELS = Path(os.environ.get("ORBITSYNTH_TEST_MODELS", "/nonexistent"))
"""A folder of real NASA meshes (optional; see the module notes)."""


# --------------------------------------------------------------------------- helpers
def _real(name):
    path = MODELS / name
    if not path.is_file():
        pytest.skip(f"real mesh {name} not available (set ORBITSYNTH_TEST_MODELS to a folder holding it)")
    return path


def _sorted_rows(a):
    a = np.asarray(a, dtype=np.float64)
    return a[np.lexsort(a.T[::-1])]


def _assert_embree_safe(model):
    """What Embree will see: finite float32 vertices, no repeated index, no zero-area face."""
    for c in model.components:
        v32 = c.mesh.vertices.astype(np.float32).astype(np.float64)
        f = c.mesh.faces
        assert np.all(np.isfinite(v32))
        assert not np.any((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2]))
        area = 0.5 * np.linalg.norm(np.cross(v32[f[:, 1]] - v32[f[:, 0]], v32[f[:, 2]] - v32[f[:, 0]]), axis=1)
        assert np.all(area > DEGENERATE_AREA_M2)
        assert len(np.unique(f)) == len(c.mesh.vertices), "unreferenced vertices left"


def _raise_one_line(match, path, **kwargs):
    kwargs.setdefault("unit_scale_m", 1.0)
    with pytest.raises(ValueError, match=match) as info:
        load_mesh(path, **kwargs)
    msg = str(info.value)
    assert "\n" not in msg
    assert info.value.__context__ is None or info.value.__suppress_context__   # no chained traceback
    return msg


def _embree_cast(model, n_rays=64, seed=0):
    """One TriangleMesh per component; rays from outside aimed at random face centroids."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    scene = rtcore_scene.EmbreeScene()
    for c in model.components:
        TriangleMesh(scene, np.ascontiguousarray(c.mesh.vertices, dtype=np.float32),
                     np.ascontiguousarray(c.mesh.faces, dtype=np.int32))
    rng = np.random.default_rng(seed)
    combined = model.combined_mesh()
    targets = combined.triangles_center[rng.integers(0, len(combined.faces), n_rays)]
    centre = model.bounds_m.mean(axis=0)
    radius = 3.0 * np.linalg.norm(np.ptp(model.bounds_m, axis=0)) + 1.0
    u = rng.normal(size=(n_rays, 3))
    origins = centre + radius * u / np.linalg.norm(u, axis=1, keepdims=True)
    dirs = targets - origins
    dist = np.linalg.norm(dirs, axis=1)
    dirs /= dist[:, None]
    hits = scene.run(origins.astype(np.float32), dirs.astype(np.float32), query="INTERSECT", output=1)
    return hits, dist


# --------------------------------------------------------------------------- synthetic files
@pytest.fixture(scope="module")
def box():
    mesh = trimesh.creation.box(extents=(2.0, 3.0, 4.0))
    mesh.apply_translation([1.0, -2.0, 0.5])
    return mesh


@pytest.mark.parametrize("ext", ["ply", "obj", "stl", "glb", "off"])
def test_single_mesh_formats(tmp_path, box, ext):
    path = tmp_path / f"box.{ext}"
    box.export(path)
    model, report = load_mesh(path, unit_scale_m=1.0)
    assert len(model.components) == 1 and model.n_triangles == 12
    (part,) = report.parts
    assert (part.faces_in, part.removed_nan, part.removed_degenerate, part.removed_duplicate,
            part.faces_out) == (12, 0, 0, 0, 12)
    # STL stores 36 unshared corners: welding within the part restores the 8 box corners
    assert len(model.components[0].mesh.vertices) == 8
    assert part.watertight and part.winding_consistent
    assert_allclose(model.bounds_m, box.bounds, atol=1e-6)
    assert model.name == "box"
    if ext != "glb":  # single-mesh formats: component named after the file stem
        assert model.component_names == ("box",)
    assert model.components[0].material == "aluminium" and model.components[0].semantic == "other"
    assert model.metadata["unit_scale_m"] == 1.0 and model.metadata["origin_offset_m"] == (0.0, 0.0, 0.0)
    _assert_embree_safe(model)


def test_unit_scale_scales_extents_exactly(tmp_path, box):
    path = tmp_path / "box_mm.ply"
    box.export(path)
    raw = trimesh.load_scene(path, process=False).bounds
    model, report = load_mesh(path, unit_scale_m=0.001)
    assert report.unit_scale_m == 0.001
    assert_allclose(model.bounds_m, raw * 0.001, rtol=1e-15, atol=0.0)
    assert_allclose(np.ptp(model.bounds_m, axis=0), [0.002, 0.003, 0.004], rtol=1e-12)


def _three_part_scene():
    """Three named parts with rotations, translations and a scale; also the world transforms."""
    tf = trimesh.transformations
    parts = {
        "Main Bus": (trimesh.creation.box(extents=(2.0, 2.0, 3.0)),
                     tf.translation_matrix([0.5, 0.0, 0.0]) @ tf.rotation_matrix(np.radians(30), [0, 0, 1])),
        "Solar Panel": (trimesh.creation.box(extents=(4.0, 0.05, 1.0)),
                        tf.translation_matrix([3.0, 1.0, -1.0]) @ tf.rotation_matrix(np.radians(90), [1, 0, 0])),
        "High-Gain Dish": (trimesh.creation.icosphere(subdivisions=1, radius=1.0),
                           tf.translation_matrix([0.0, 0.0, 2.0]) @ tf.scale_matrix(0.5)
                           @ tf.rotation_matrix(np.radians(-40), [0, 1, 1])),
    }
    scene = trimesh.Scene()
    for name, (mesh, T) in parts.items():
        scene.add_geometry(mesh, node_name=name, geom_name=name + " mesh", transform=T)
    return scene, parts


def test_scene_keeps_parts_names_and_bakes_transforms(tmp_path):
    scene, parts = _three_part_scene()
    path = tmp_path / "craft.glb"
    scene.export(path)
    for scale in (1.0, 0.001):
        model, report = load_mesh(path, unit_scale_m=scale)
        assert sorted(model.component_names) == ["high_gain_dish", "main_bus", "solar_panel"]
        assert report.faces_out == report.faces_in == sum(len(m.faces) for m, _ in parts.values())
        by_name = {c.name: c for c in model.components}
        for src_name, (mesh, T) in parts.items():
            comp = by_name[src_name.lower().replace(" ", "_").replace("-", "_")]
            expected = (mesh.vertices @ T[:3, :3].T + T[:3, 3]) * scale   # independent of the loader
            assert len(comp.mesh.faces) == len(mesh.faces)
            assert_allclose(_sorted_rows(comp.mesh.vertices), _sorted_rows(expected),
                            rtol=0, atol=2e-6 * scale)   # glb stores float32
        # heuristics from the node names
        assert (by_name["solar_panel"].material, by_name["solar_panel"].semantic) == ("solar_cell", "solar_panel")
        assert (by_name["high_gain_dish"].material, by_name["high_gain_dish"].semantic) == ("dish", "dish")
        assert (by_name["main_bus"].material, by_name["main_bus"].semantic) == ("aluminium", "bus")
        _assert_embree_safe(model)


def test_instances_and_name_collisions_become_unique_components(tmp_path):
    tf = trimesh.transformations
    scene = trimesh.Scene()
    shared = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    scene.add_geometry(shared, node_name="Panel A", geom_name="panel", transform=tf.translation_matrix([2, 0, 0]))
    scene.add_geometry(shared, node_name="panel-a", geom_name="panel", transform=tf.translation_matrix([-2, 0, 0]))
    scene.add_geometry(trimesh.creation.icosphere(1), node_name="PANEL_A", geom_name="ball")
    path = tmp_path / "instances.glb"
    scene.export(path)
    model, _ = load_mesh(path, unit_scale_m=1.0)
    assert sorted(model.component_names) == ["panel_a", "panel_a_2", "panel_a_3"]
    centres = sorted(round(float(c.mesh.bounds.mean(axis=0)[0]), 6) for c in model.components)
    assert centres == [-2.0, 0.0, 2.0]   # each instance carries its own transform


def test_material_from_file_material_name_and_maps(tmp_path):
    scene = trimesh.Scene()
    wrapped = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    wrapped.visual = TextureVisuals(material=PBRMaterial(name="foil_gold", baseColorFactor=[200, 150, 0, 255]))
    scene.add_geometry(wrapped, node_name="thing", geom_name="thing")
    scene.add_geometry(trimesh.creation.icosphere(1), node_name="mystery", geom_name="mystery",
                       transform=trimesh.transformations.translation_matrix([3, 0, 0]))
    path = tmp_path / "materials.glb"
    scene.export(path)

    model, _ = load_mesh(path, unit_scale_m=1.0, default_material="white_paint")
    got = {c.name: (c.material, c.semantic) for c in model.components}
    assert got == {"thing": ("gold_mli", "other"), "mystery": ("white_paint", "other")}

    model, _ = load_mesh(path, unit_scale_m=1.0, material_map={"foil_gold": "silver_mli", "mystery": "dish"},
                         semantic_map={"thing": "radiator"})
    got = {c.name: (c.material, c.semantic) for c in model.components}
    assert got == {"thing": ("silver_mli", "radiator"), "mystery": ("dish", "other")}

    summary = component_summary(model)
    assert sorted(summary, key=lambda d: d["name"]) == [
        {"name": "mystery", "material": "dish", "semantic": "other", "faces": 80},
        {"name": "thing", "material": "silver_mli", "semantic": "radiator", "faces": 12}]


@pytest.mark.parametrize("node, material, semantic", [
    ("Solar Array Wing", "solar_cell", "solar_panel"),
    ("HGA_Reflector", "dish", "dish"),
    ("gold foil MLI", "gold_mli", "other"),
    ("beta cloth silver", "silver_mli", "other"),
    ("black radiator", "black_radiator", "radiator"),
    ("white radiator", "white_paint", "radiator"),
    ("magnetometerBoom", "aluminium", "boom"),
    ("RTG", "titanium", "rtg"),
    ("main engine nozzle", "titanium", "engine"),
    ("RCS thruster", "titanium", "thruster"),
    ("UHF antenna", "aluminium", "antenna"),
    ("mystery", "aluminium", "other"),
])
def test_name_heuristics(tmp_path, node, material, semantic):
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box(), node_name=node, geom_name="g")
    path = tmp_path / "h.glb"
    scene.export(path)
    (comp,) = load_mesh(path, unit_scale_m=1.0)[0].components
    assert (comp.material, comp.semantic) == (material, semantic)
    assert comp.material in MATERIALS and comp.semantic in SEMANTIC_CLASSES


def test_recentre_modes(tmp_path):
    big = trimesh.creation.box(extents=(2.0, 4.0, 6.0))
    small = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    small.apply_translation([5.0, 0.0, 0.0])
    mesh = trimesh.util.concatenate([big, small])
    mesh.apply_translation([1000.0, 2000.0, 3000.0])
    path = tmp_path / "far.ply"
    mesh.export(path)
    mesh = trimesh.load_mesh(path, process=False)   # reference: what the file holds (float32)

    model, report = load_mesh(path, unit_scale_m=1.0)
    assert_allclose(model.bounds_m, mesh.bounds)
    model, report = load_mesh(path, unit_scale_m=1.0, recentre="bbox")
    assert_allclose(model.bounds_m[0], -model.bounds_m[1], atol=1e-9)
    assert_allclose(report.origin_offset_m, mesh.bounds.mean(axis=0), atol=1e-9)
    assert model.metadata["origin_offset_m"] == report.origin_offset_m
    model, report = load_mesh(path, unit_scale_m=0.5, recentre="centroid")
    a = mesh.area_faces
    expected = 0.5 * (a[:, None] * mesh.triangles_center).sum(axis=0) / a.sum()
    assert_allclose(report.origin_offset_m, expected, atol=1e-9)
    assert_allclose(model.bounds_m, 0.5 * mesh.bounds - expected, atol=1e-9)


# --------------------------------------------------------------------------- repair
def _planted_ply(tmp_path):
    """A 4x4 grid (32 good faces, 1 file unit = 1 mm) plus planted defects, their counts."""
    n = 5
    xs, ys = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    v = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(n * n)])
    good = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            good += [[a, b, c], [a, c, d]]
    good = np.array(good)
    extra = np.array([
        [0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [2.0, 0.0, 1.0],      # 25-27 collinear
        [10.0, 0.0, 0.0], [10.0 + 1e-3, 0.0, 0.0], [10.0, 2e-4, 0.0],  # 28-30 area 1e-7 mm^2
        [100.0, 100.0, 100.0],                                   # 31 unreferenced
        v[0], v[n], v[n + 1],                                    # 32-34 copies of corners 0, n, n+1
    ])
    v = np.vstack([v, extra])
    degenerate_index = [[0, 0, 1], [2, 3, 3], [4, 5, 4]]
    degenerate_area = [[25, 26, 27], [27, 25, 26]]
    tiny = [[28, 29, 30]]
    duplicates = [good[3], good[7], good[7][::-1], np.roll(good[9], 1),  # same triple, any winding
                  [32, 33, 34]]                                         # = good[0] after welding
    dup_of_degenerate = [[0, 1, 0]]                                      # counted as degenerate first
    faces = np.vstack([good, degenerate_index, degenerate_area, tiny, duplicates, dup_of_degenerate])
    path = tmp_path / "planted.ply"
    trimesh.Trimesh(v, faces, process=False).export(path)
    raw = trimesh.load_scene(path, process=False).geometry
    (g,) = raw.values()
    assert len(g.faces) == len(faces) and len(g.vertices) == len(v)   # the file holds what we planted
    return path, dict(good=len(good), degenerate=3 + 2 + 1, tiny=1, duplicate=5)


def test_planted_degenerate_and_duplicate_counts(tmp_path):
    path, planted = _planted_ply(tmp_path)
    # millimetre file: the 1e-7 mm^2 sliver is 1e-13 m^2 -> degenerate
    model, report = load_mesh(path, unit_scale_m=0.001)
    (part,) = report.parts
    assert part.removed_nan == 0
    assert part.removed_degenerate == planted["degenerate"] + planted["tiny"]
    assert part.removed_duplicate == planted["duplicate"]
    assert part.faces_out == planted["good"] == model.n_triangles
    assert part.faces_in == part.faces_out + part.removed_degenerate + part.removed_duplicate
    mesh = model.components[0].mesh
    assert len(mesh.vertices) == 25   # welded copies merged, collinear/sliver/unused vertices gone
    assert_allclose(model.bounds_m, [[0, 0, 0], [0.004, 0.004, 0]], atol=1e-15)
    _assert_embree_safe(model)
    # metre file: the same sliver is 1e-7 m^2 and is kept
    model, report = load_mesh(path, unit_scale_m=1.0)
    assert report.removed_degenerate == planted["degenerate"]
    assert report.faces_out == planted["good"] + planted["tiny"]
    assert "degenerate" in report.summary() and "\n" not in report.summary()


def test_nan_and_inf_vertices_are_removed_and_reported(tmp_path):
    path = tmp_path / "nan.obj"
    path.write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 2 0 0\nv 2 1 0\nv 0 inf 0\n"
                    "f 1 2 3\nf 1 3 4\nf 2 4 3\nf 2 5 6\nf 2 6 4\nf 7 5 6\n")
    model, report = load_mesh(path, unit_scale_m=1.0)
    assert (report.removed_nan, report.removed_degenerate, report.removed_duplicate) == (3, 0, 0)
    assert report.faces_in == 6 and report.faces_out == 3
    mesh = model.components[0].mesh
    assert np.all(np.isfinite(mesh.vertices)) and len(mesh.vertices) == 5
    assert "3 non-finite" in report.summary()
    _assert_embree_safe(model)


def test_part_emptied_by_nan_is_dropped_and_reported(tmp_path):
    path = tmp_path / "two.obj"
    path.write_text("o good\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
                    "o bad\nv nan 0 0\nv 1 1 1\nv 0 1 1\nf 4 5 6\n")
    model, report = load_mesh(path, unit_scale_m=1.0)
    assert model.component_names == ("good",)
    assert report.dropped_parts == ("bad",)
    bad = next(p for p in report.parts if p.name == "bad")
    assert (bad.faces_in, bad.removed_nan, bad.faces_out, bad.dropped) == (1, 1, 0, True)
    assert "dropped: bad" in report.summary()


def test_float32_collapse_far_from_origin(tmp_path):
    # 1 cm triangles 10 000 km from the origin: distinct in float64, degenerate in float32
    path = tmp_path / "far_tiny.obj"
    path.write_text("v 1e7 0 0\nv 10000000.01 0 0\nv 1e7 0.01 0\nv 10000000.01 0.01 0\n"
                    "f 1 2 3\nf 2 4 3\n")
    msg = _raise_one_line("nothing renderable.*2 degenerate", path)
    assert str(path) in msg
    model, report = load_mesh(path, unit_scale_m=1.0, recentre="bbox")
    assert model.n_triangles == 2 and report.removed_degenerate == 0
    _assert_embree_safe(model)


# --------------------------------------------------------------------------- errors
@pytest.mark.parametrize("ext", ["obj", "stl", "ply", "glb", "off"])
def test_empty_file(tmp_path, ext):
    path = tmp_path / f"empty.{ext}"
    path.write_bytes(b"")
    assert str(path) in _raise_one_line(f"mesh file {path}", path)


def test_only_degenerate_faces(tmp_path):
    path = tmp_path / "flat.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\nf 1 1 2\n")
    msg = _raise_one_line(r"nothing renderable left after repair: all 2 faces removed .*2 degenerate", path)
    assert str(path) in msg


def test_only_nan_faces(tmp_path):
    path = tmp_path / "allnan.obj"
    path.write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    _raise_one_line(r"all 1 faces removed \(1 non-finite", path)


def test_points_only(tmp_path):
    path = tmp_path / "points.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    _raise_one_line("contains no triangles", path)


@pytest.mark.parametrize("case, match", [
    ("missing", "does not exist"),
    ("directory", "is a directory"),
    ("text_as_glb", "cannot be read as glb"),
    ("garbage_ply", "cannot be read as ply"),
    ("bad_index_obj", "cannot be read as obj|corrupt"),
    ("unsupported", "unsupported format '.foo'; allowed: .*glb"),
])
def test_unreadable_inputs(tmp_path, case, match):
    path = {
        "missing": tmp_path / "nope.glb",
        "directory": tmp_path,
        "text_as_glb": tmp_path / "text.glb",
        "garbage_ply": tmp_path / "garbage.ply",
        "bad_index_obj": tmp_path / "bad.obj",
        "unsupported": tmp_path / "model.foo",
    }[case]
    if case == "text_as_glb":
        path.write_text("this is not a binary glTF\n")
    elif case == "garbage_ply":
        path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n\x00\x01")
    elif case == "bad_index_obj":
        path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    elif case == "unsupported":
        path.write_text("solid\n")
    assert str(path) in _raise_one_line(match, path)


@pytest.mark.parametrize("scale", [0, 0.0, -1.0, float("nan"), float("inf"), "1", None, True])
def test_unit_scale_validated(tmp_path, box, scale):
    path = tmp_path / "box.ply"
    box.export(path)
    msg = _raise_one_line("unit_scale_m must be a finite number > 0", path, unit_scale_m=scale)
    assert repr(scale) in msg


def test_unit_scale_is_required(tmp_path, box):
    path = tmp_path / "box.ply"
    box.export(path)
    with pytest.raises(TypeError):
        load_mesh(path)


@pytest.mark.parametrize("kwargs, match", [
    (dict(material_map={"box": "unobtainium"}), r"material_map\['box'\] must be one of gold_mli, .*titanium; got 'unobtainium'"),
    (dict(material_map={"no_such_part": "dish"}), r"material_map keys \['no_such_part'\] name no part .*parts: box"),
    (dict(semantic_map={"box": "spaceship"}), r"semantic_map\['box'\] must be one of bus, "),
    (dict(material_map=["box"]), "material_map must be a dict"),
    (dict(default_material="gold"), "default_material must be one of .*got 'gold'"),
    (dict(recentre="origin"), "recentre must be one of none, bbox, centroid; got 'origin'"),
    (dict(name=""), "name must be a non-empty string"),
])
def test_invalid_options(tmp_path, box, kwargs, match):
    path = tmp_path / "box.ply"
    box.export(path)
    _raise_one_line(match, path, **kwargs)


def test_report_is_frozen_and_summary_is_one_line(tmp_path, box):
    path = tmp_path / "box.stl"
    box.export(path)
    _, report = load_mesh(path, unit_scale_m=1.0)
    assert isinstance(report, MeshReport)
    with pytest.raises(dataclasses.FrozenInstanceError):
        report.unit_scale_m = 2.0
    assert report.summary() == ("box.stl: 1/1 parts, 12/12 triangles kept (removed 0 non-finite, "
                                "0 degenerate, 0 duplicate); 1/1 parts watertight, 0 winding-inconsistent; "
                                "unit_scale_m=1")


@pytest.fixture(scope="module")
def craft_glb(tmp_path_factory):
    path = tmp_path_factory.mktemp("prop") / "craft.glb"
    _three_part_scene()[0].export(path)
    return path


@settings(max_examples=25, deadline=None)
@given(scale=st.floats(1e-4, 1e3))
def test_scale_property(craft_glb, scale):
    raw = trimesh.load_scene(craft_glb, process=False)
    model, report = load_mesh(craft_glb, unit_scale_m=scale)
    assert report.faces_out == report.faces_in
    assert_allclose(model.bounds_m, raw.bounds * scale, rtol=1e-9, atol=1e-12 * scale)


# --------------------------------------------------------------------------- real NASA meshes
def _independent_counts(path):
    """Per node: (faces, degenerate, duplicate-after-degenerate) from the raw trimesh load."""
    scene = trimesh.load_scene(path, process=False)
    out = {}
    for node in scene.graph.nodes_geometry:
        T, geom_name = scene.graph[node]
        g = scene.geometry[geom_name]
        assert np.allclose(T, np.eye(4))                      # these files have transforms baked in
        v, f = g.vertices, g.faces
        assert len(np.unique(v, axis=0)) == len(v)            # already welded when exported
        assert np.all(np.isfinite(v))
        area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
        deg = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2]) | (area <= 1e-12)
        rest = np.sort(f[~deg], axis=1)
        dup = len(rest) - len(np.unique(rest, axis=0))
        out[node] = (len(f), int(deg.sum()), dup)
    return out


@pytest.fixture(scope="module")
def cassini():
    path = _real("cassini.glb")
    return path, *load_mesh(path, unit_scale_m=1.0)


@pytest.fixture(scope="module")
def icesat2():
    path = _real("icesat2.glb")
    t0 = time.perf_counter()
    model, report = load_mesh(path, unit_scale_m=1.0)
    return path, model, report, time.perf_counter() - t0


def _check_against_independent(path, report):
    counts = _independent_counts(path)
    assert {p.source_node for p in report.parts} == set(counts)
    for p in report.parts:
        assert (p.faces_in, p.removed_degenerate, p.removed_duplicate) == counts[p.source_node], p.name
        assert p.removed_nan == 0
        assert p.faces_out == p.faces_in - p.removed_degenerate - p.removed_duplicate


def test_cassini(cassini):
    path, model, report = cassini
    _check_against_independent(path, report)
    assert len(model.components) == 10 and report.faces_in == 25_724
    assert model.n_triangles == report.faces_out == 25_724 - report.removed_degenerate - report.removed_duplicate
    # measured on the file: 1 duplicate face (black_krinkle), 0 degenerate, aluminum and dish
    # winding-inconsistent
    assert (report.removed_degenerate, report.removed_duplicate) == (0, 1)
    assert next(p for p in report.parts if p.removed_duplicate).name == "black_krinkle"
    assert {p.name for p in report.parts if not p.winding_consistent} == {"aluminum", "dish_dish_ao"}
    assert report.n_watertight == 0
    assert_allclose(np.ptp(model.bounds_m, axis=0), [17.98, 11.66, 13.11], atol=0.006)
    assert_allclose(model.bounds_m, [[-9.00, -8.27, -11.07], [8.98, 3.39, 2.04]], atol=0.006)
    assert {c.name: c.material for c in model.components}["foil_gold"] == "gold_mli"
    _assert_embree_safe(model)


def test_icesat2_fast_and_repaired(icesat2):
    path, model, report, seconds = icesat2
    assert seconds < 10.0
    _check_against_independent(path, report)
    assert len(model.components) == 26 and report.faces_in == 201_656
    assert report.removed_degenerate > 2_000 and report.removed_duplicate > 200
    assert_allclose(np.ptp(model.bounds_m, axis=0), [3.74, 2.39, 7.56], atol=0.006)
    _assert_embree_safe(model)


# --------------------------------------------------------------------------- Embree
@pytest.mark.parametrize("which", ["craft", "planted", "cassini", "icesat2", "extra_hubble", "extra_juno"])
def test_models_go_into_embree(request, tmp_path, which):
    if which == "craft":
        model = load_mesh(request.getfixturevalue("craft_glb"), unit_scale_m=1.0)[0]
    elif which == "planted":
        model = load_mesh(_planted_ply(tmp_path)[0], unit_scale_m=0.001)[0]
    elif which in ("cassini", "icesat2"):
        model = request.getfixturevalue(which)[1]
    else:
        model = load_mesh(_real(f"{which}.glb"), unit_scale_m=1.0)[0]
    hits, dist = _embree_cast(model)
    hit = hits["geomID"] >= 0
    assert hit.mean() >= 0.9       # rays aimed at face centroids (edge-on grazes may miss)
    assert np.all(np.isfinite(hits["tfar"][hit]))
    assert np.all(hits["tfar"][hit] <= dist[hit] * (1 + 1e-4) + 1e-4)
    assert np.all(hits["geomID"][hit] < len(model.components))
    n_faces = np.array([len(c.mesh.faces) for c in model.components])
    assert np.all(hits["primID"][hit] < n_faces[hits["geomID"][hit]])
