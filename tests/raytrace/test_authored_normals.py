"""User meshes: the crease angle per mesh, and the file's own vertex normals as shading normals.

References are closed forms: the facet normals of a polygonal cylinder, the radial normal of a
sphere (barycentric interpolation of radial vertex normals is radial at the hit point, since
the hit point is the same interpolation of the vertices), and the gradient of an ellipsoid.
"""

import json
import math

import numpy as np
import pytest
import trimesh

import cli
from orbit.pose import look_at
from raytrace.camera import Camera
from raytrace.meshio import load_mesh
from raytrace.scene import Scene
from raytrace.scenefile import load_scene_file

SECTIONS = 12  # cylinder facets 30° apart: smoothed by the default 30° crease rule (cos 30° ≥ cos 30°)


def _pose(cam_pos_body):
    R = look_at(np.asarray(cam_pos_body, float), up_ref_lvlh=(0.0, 0.0, 1.0))
    return R, -R @ np.asarray(cam_pos_body, float)


def _cam():
    return Camera(width=96, height=72, fx=110.0, fy=110.0, cx=47.5, cy=35.5)


def _render(model, cam_pos=(3.0, -4.0, 2.5)):
    cam = _cam()
    R, t = _pose(cam_pos)
    g = Scene(model).render_geometry(cam, R, t)
    assert g.mask.sum() > 500
    return g, cam, R, t


def _angle_deg(a, b):
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def _facing(g, cam, n_cam, min_cos=0.3):
    """Pixels whose normal n_cam (one per hit pixel) is within acos(min_cos) of the view ray:
    off the limb, where the renderer bends shading normals that face away from the viewer."""
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(float)
    ray = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1)[g.mask]
    return -np.sum(n_cam * ray, axis=1) / np.linalg.norm(ray, axis=1) > min_cos


def _hit_points_body(g, cam, R, t):
    """Body-frame hit point of every pixel from its depth: p_cam = z (x_n, y_n, 1)."""
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(float)
    ray = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1)
    p_cam = ray * np.where(g.mask, g.depth_m, 0.0)[..., None]
    return (p_cam - t) @ R  # R.T (p_cam - t), row-wise


@pytest.fixture(scope="module")
def flat_cylinder(tmp_path_factory):
    """A 12-sided cylinder, r = 1 m, h = 1.6 m, as glTF without normals (a CAD part's facets)."""
    path = tmp_path_factory.mktemp("cyl") / "cyl.glb"
    trimesh.creation.cylinder(radius=1.0, height=1.6, sections=SECTIONS).export(path, include_normals=False)
    return path


def _facet_normals():
    """Closed form: side facet k between azimuths 2πk/n and 2π(k+1)/n faces its mid azimuth; caps ±z."""
    mid = (np.arange(SECTIONS) + 0.5) * 2 * math.pi / SECTIONS
    side = np.column_stack([np.cos(mid), np.sin(mid), np.zeros(SECTIONS)])
    return np.vstack([side, [[0, 0, 1.0], [0, 0, -1.0]]])


def test_crease_zero_renders_facets_flat_and_default_smooths_them(flat_cylinder):
    model, _ = load_mesh(flat_cylinder, unit_scale_m=1.0, crease_angle_deg=0)
    assert model.components[0].corner_normals is None  # the file has no normals
    g, cam, R, t = _render(model)
    n_body = g.normal_cam[g.mask] @ R  # camera → body
    ang = _angle_deg(n_body[:, None, :], _facet_normals()[None, :, :])
    assert ang.min(axis=1).max() < 1e-3  # every pixel: exactly one of the closed-form facet normals
    # constant per face: all pixels of a triangle share its normal
    faces = g.face_index[g.mask]
    for f in np.unique(faces):
        nf = n_body[faces == f]
        assert np.abs(nf - nf[0]).max() < 1e-6
    seen = np.unique(ang.argmin(axis=1))
    assert len(seen) >= 5  # several side facets and a cap are in view

    smooth, _ = load_mesh(flat_cylinder, unit_scale_m=1.0)  # default 30°: side facets blend
    g30, *_ = _render(smooth)
    n30 = g30.normal_cam[g30.mask] @ R
    ang30 = _angle_deg(n30[:, None, :], _facet_normals()[None, :, :]).min(axis=1)
    assert np.mean(ang30 > 1.0) > 0.3
    assert np.array_equal(g30.mask, g.mask)  # same silhouette: only the shading normals differ


def _sphere(count=(16, 16)):
    s = trimesh.creation.uv_sphere(radius=1.0, count=list(count))
    s.vertex_normals = s.vertices / np.linalg.norm(s.vertices, axis=1)[:, None]
    return s


@pytest.mark.parametrize("ext", ["glb", "obj"])
def test_authored_sphere_normals_are_the_analytic_normal_at_the_hit(tmp_path, ext):
    path = tmp_path / f"sphere.{ext}"
    s = _sphere()
    (s.export(path, include_normals=True) if ext == "obj" else s.export(path))
    if ext == "obj":
        assert "\nvn " in path.read_text()
    model, _ = load_mesh(path, unit_scale_m=1.0)
    assert model.components[0].corner_normals is not None and model.metadata["authored_normal_parts"] == 1
    g, cam, R, t = _render(model)
    p = _hit_points_body(g, cam, R, t)[g.mask]
    n_true_cam = (p / np.linalg.norm(p, axis=1)[:, None]) @ R.T
    core = _facing(g, cam, n_true_cam)
    assert core.sum() > 0.8 * len(core)
    err = _angle_deg(g.normal_cam[g.mask], n_true_cam)[core]
    assert err.max() < 0.02  # float32 normals and depth; interpolation of radial normals is radial
    # the crease rule (angle-weighted face normals) is not radial inside a triangle
    crease, _ = load_mesh(path, unit_scale_m=1.0, authored_normals=False)
    assert crease.components[0].corner_normals is None
    gc, *_ = _render(crease)
    err_c = _angle_deg(gc.normal_cam[g.mask], n_true_cam)[core]
    assert err_c.max() > 10 * max(err.max(), 0.01)
    flat, _ = load_mesh(path, unit_scale_m=1.0, crease_angle_deg=0)  # authored normals win over the crease
    gf, *_ = _render(flat)
    assert np.array_equal(gf.normal_cam, g.normal_cam)


def test_reversed_winding_turns_the_normals_and_zero_normals_fall_back(tmp_path):
    s = _sphere((12, 12))
    n = np.array(s.vertex_normals)
    bad = 40
    n[bad] = 0.0  # a zero normal in the file
    inv = trimesh.Trimesh(s.vertices, s.faces[:, ::-1], vertex_normals=n, process=False)  # inward winding
    path = tmp_path / "inv.obj"
    inv.export(path, include_normals=True)
    model, _ = load_mesh(path, unit_scale_m=1.0)
    comp = model.components[0]
    V, F = comp.mesh.vertices, comp.mesh.faces
    geo = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    cn = comp.corner_normals
    ok = np.isfinite(cn).all(axis=2)
    radial = V[F] / np.linalg.norm(V[F], axis=2, keepdims=True)
    assert np.all(np.einsum("fkj,fj->fk", cn[ok.all(axis=1)], geo[ok.all(axis=1)]) > 0)  # the winding's side
    np.testing.assert_allclose(cn[ok], -radial[ok], atol=1e-6)  # inward, as the winding says
    at_bad = np.all(np.isclose(V[F], s.vertices[bad]), axis=2)
    assert at_bad.sum() >= 3 and not ok[at_bad].any() and ok[~at_bad].all()
    scene = Scene(model)
    fallback = Scene(load_mesh(path, unit_scale_m=1.0, authored_normals=False)[0]).corner_normal
    assert np.array_equal(scene.corner_normal[at_bad], fallback[at_bad])
    # rendered normals face the camera either way, and are the outward radial normal there
    g, cam, R, t = _render(model)
    p = _hit_points_body(g, cam, R, t)[g.mask]
    n_true_cam = (p / np.linalg.norm(p, axis=1)[:, None]) @ R.T
    err = _angle_deg(g.normal_cam[g.mask], n_true_cam)
    far = ~np.isin(g.face_index[g.mask], np.flatnonzero(at_bad.any(axis=1))) & _facing(g, cam, n_true_cam)
    assert err[far].max() < 0.02


def test_node_transform_applies_the_inverse_transpose(tmp_path):
    s = _sphere((12, 12))
    S = np.diag([2.0, 1.0, 0.5, 1.0])  # unit sphere → ellipsoid x²/4 + y² + 4 z² = 1
    scene = trimesh.Scene()
    scene.add_geometry(s, node_name="ell", transform=S)
    path = tmp_path / "ell.glb"
    scene.export(path)
    model, _ = load_mesh(path, unit_scale_m=1.0)
    comp = model.components[0]
    P = comp.mesh.vertices[comp.mesh.faces]
    grad = P * np.array([1 / 4, 1.0, 4.0])  # ∇(x²/4 + y² + 4z²) / 2
    cn = comp.corner_normals
    ok = np.isfinite(cn).all(axis=2)
    assert ok.mean() > 0.9
    assert _angle_deg(cn[ok], grad[ok]).max() < 1e-4


def test_scene_file_mesh_keys(tmp_path):
    s = _sphere((12, 12))
    s.export(tmp_path / "s.glb")
    base = {"camera": {"K": [[100, 0, 31.5], [0, 100, 23.5], [0, 0, 1]], "width": 64, "height": 48,
                       "R_cam_from_body": [1, 0, 0, 0, 1, 0, 0, 0, 1], "t_cam_m": [0, 0, 5]},
            "sun": {"sun_dir_body": [0, 0, -1]}}

    def load(**entry):
        path = tmp_path / "scene.json"
        path.write_text(json.dumps({**base, "meshes": [{"path": "s.glb", "albedo": 0.5, **entry}]}))
        return load_scene_file(str(path)).model.components[0]

    assert load().corner_normals is not None
    c = load(authored_normals=False, crease_angle_deg=0)
    assert c.corner_normals is None and c.crease_angle_rad == 0.0
    assert load(crease_angle_deg=180).crease_angle_rad == pytest.approx(math.pi)
    for entry, words in (({"crease_angle_deg": 181}, "meshes[0].crease_angle_deg must be"),
                         ({"crease_angle_deg": "30"}, "meshes[0].crease_angle_deg must be"),
                         ({"crease_angle_deg": True}, "meshes[0].crease_angle_deg must be"),
                         ({"authored_normals": 1}, "meshes[0].authored_normals must be true or false")):
        with pytest.raises(ValueError) as exc:
            load(**entry)
        assert words in str(exc.value) and "\n" not in str(exc.value)


@pytest.mark.parametrize("value", ["181", "-0.5", "nan", "inf", "thirty", ""])
def test_bad_mesh_crease_deg_exits_2_with_one_line(flat_cylinder, tmp_path, capsys, value):
    with pytest.raises(SystemExit) as exc:
        cli.main(["--mesh", str(flat_cylinder), "--mesh-crease-deg", value, "--frames", "1", "--json",
                  "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("cli.py: error: argument --mesh-crease-deg: must be") and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_mesh_crease_deg_needs_mesh_and_reaches_the_model(flat_cylinder, tmp_path, capsys):
    assert cli.main(["--target", "cassini", "--mesh-crease-deg", "10", "--frames", "1", "--json"]) == 2
    err = capsys.readouterr().err
    assert "argument --mesh-crease-deg: only with --mesh" in err and err.count("\n") == 1
    args = cli.build_parser().parse_args(["--mesh", str(flat_cylinder), "--mesh-crease-deg", "0", "--frames", "1"])
    cfg, given = cli.resolve_config(args)
    plan = cli.plan_sequence(cfg, given)
    assert plan["model_spec"][3] == 0.0
    assert plan["model"].components[0].crease_angle_rad == 0.0


def test_flat_authored_normals_keep_a_box_faceted_whatever_the_crease(tmp_path):
    box = trimesh.creation.box(extents=(1.0, 1.4, 0.8))
    box.unmerge_vertices()  # three vertices per face, each with its face's normal (a flat-shaded export)
    F = box.faces
    flat = np.cross(box.vertices[F[:, 1]] - box.vertices[F[:, 0]], box.vertices[F[:, 2]] - box.vertices[F[:, 0]])
    n = np.zeros_like(box.vertices)
    n[F.ravel()] = np.repeat(flat / np.linalg.norm(flat, axis=1)[:, None], 3, axis=0)
    mesh = trimesh.Trimesh(box.vertices, F, vertex_normals=n, process=False)
    path = tmp_path / "box.obj"
    mesh.export(path, include_normals=True)
    model, _ = load_mesh(path, unit_scale_m=1.0, crease_angle_deg=180)  # would round every edge
    g, cam, R, t = _render(model)
    n_body = g.normal_cam[g.mask] @ R
    axes = np.vstack([np.eye(3), -np.eye(3)])
    assert _angle_deg(n_body[:, None, :], axes[None]).min(axis=1).max() < 1e-3
    rounded, _ = load_mesh(path, unit_scale_m=1.0, crease_angle_deg=180, authored_normals=False)
    gr, *_ = _render(rounded)
    assert _angle_deg((gr.normal_cam[gr.mask] @ R)[:, None, :], axes[None]).min(axis=1).max() > 20
