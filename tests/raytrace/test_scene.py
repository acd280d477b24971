"""Geometry pass: exact depth, normals and ids against closed forms and a brute-force ray caster."""

import math

import numpy as np
import pytest
import trimesh

from orbit.pose import look_at
from orbit.rotations import axis_angle
from raytrace.camera import Camera
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene
from tests.raytrace.oracles import point_mesh_distance


def model_of(*meshes, names=None):
    names = names or [f"part{k}" for k in range(len(meshes))]
    return TargetModel("test", tuple(Component(n, m, "white_paint", "bus", 1.0) for n, m in zip(names, meshes)))


def pose_looking_at_origin(cam_pos_body, up=(0.0, 0.0, 1.0)):
    """R_cam_from_body, t_cam for a camera at cam_pos_body looking at the body origin."""
    R = look_at(np.asarray(cam_pos_body, float), up_ref_lvlh=up)
    return R, -R @ np.asarray(cam_pos_body, float)


def pixel_rays_cam(cam):
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(float)
    return np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1)


def angle_deg(a, b):
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


# ------------------------------------------------------------------ analytic scenes
def test_plane_depth_and_normal_exact():
    # a 20 m square plate in the body x-y plane, camera tilted 50 deg from its normal
    plate = trimesh.creation.box((20.0, 20.0, 0.02))
    scene = Scene(model_of(plate))
    cam = Camera(width=320, height=240, fx=300.0, fy=300.0, cx=159.5, cy=119.5)
    pos = 15.0 * np.array([math.sin(math.radians(50)), 0.0, math.cos(math.radians(50))])
    R, t = pose_looking_at_origin(pos, up=(0, 1, 0))
    g = scene.render_geometry(cam, R, t, ray_distance=True, geometric_normal=True)
    hit = g.mask
    assert hit.sum() > 1000
    # closed form: plane z_body = +0.01 (top face); ray p = o + s d (body), s = z-depth
    d_cam = pixel_rays_cam(cam)
    d_body = d_cam @ R  # R^T d for each pixel
    o_body = -R.T @ t
    s = (0.01 - o_body[2]) / d_body[..., 2]
    np.testing.assert_allclose(g.depth_m[hit], s[hit], rtol=1e-6)  # float32 storage
    np.testing.assert_allclose(g.ray_distance_m[hit], (s * np.linalg.norm(d_cam, axis=-1))[hit], rtol=1e-6)
    n_cam_expected = R @ np.array([0.0, 0.0, 1.0])
    assert angle_deg(g.normal_cam[hit], n_cam_expected).max() < 1e-4
    assert angle_deg(g.normal_geom_cam[hit], n_cam_expected).max() < 1e-4


@pytest.mark.parametrize("grazing_deg", [80.0, 88.0, 89.5])
def test_thin_plate_at_grazing_angles(grazing_deg):
    plate = trimesh.creation.box((10.0, 10.0, 0.001))
    scene = Scene(model_of(plate))
    cam = Camera(width=400, height=300, fx=500.0, fy=500.0, cx=199.5, cy=149.5)
    a = math.radians(grazing_deg)
    pos = 12.0 * np.array([math.sin(a), 0.0, math.cos(a)])
    R, t = pose_looking_at_origin(pos, up=(0, 1, 0))
    g = scene.render_geometry(cam, R, t, geometric_normal=True)
    top = g.mask & (g.normal_geom_cam @ (R @ [0, 0, 1.0]) > 0.99)
    assert top.sum() > 50
    d_body = pixel_rays_cam(cam) @ R
    o_body = -R.T @ t
    s = (0.0005 - o_body[2]) / d_body[..., 2]
    np.testing.assert_allclose(g.depth_m[top], s[top], rtol=1e-5)
    assert angle_deg(g.normal_cam[top], R @ [0, 0, 1.0]).max() < 0.05


def test_cube_faces_depth_and_normals():
    cube = trimesh.creation.box((2.0, 2.0, 2.0))
    scene = Scene(model_of(cube))
    cam = Camera(width=300, height=300, fx=400.0, fy=400.0, cx=149.5, cy=149.5)
    pos = np.array([6.0, 4.0, 3.0])
    R, t = pose_looking_at_origin(pos)
    g = scene.render_geometry(cam, R, t)
    d_body = pixel_rays_cam(cam) @ R
    o_body = -R.T @ t
    # closed form: slab intersection of the ray with the cube |x|,|y|,|z| <= 1 (entry point)
    with np.errstate(divide="ignore"):
        t1 = (-1.0 - o_body) / d_body
        t2 = (1.0 - o_body) / d_body
    t_near = np.minimum(t1, t2).max(axis=-1)
    t_far = np.maximum(t1, t2).min(axis=-1)
    hit_expected = t_near <= t_far
    inner = hit_expected & ~np.isclose(t_near, t_far, rtol=1e-3)
    assert np.array_equal(g.mask[inner], hit_expected[inner])
    np.testing.assert_allclose(g.depth_m[inner], t_near[inner], rtol=1e-6)
    axis = np.argmax(np.minimum(t1, t2), axis=-1)  # the slab that was entered last
    n_body = np.zeros(d_body.shape)
    np.put_along_axis(n_body, axis[..., None], -np.sign(np.take_along_axis(d_body, axis[..., None], -1)), -1)
    away_from_edges = inner & (np.sort(np.minimum(t1, t2), axis=-1)[..., 1] < t_near - 1e-3)
    n_cam = n_body @ R.T
    assert angle_deg(g.normal_cam[away_from_edges], n_cam[away_from_edges]).max() < 0.05  # faceted cube


def test_sphere_depth_normals_and_silhouette():
    R_s, dist = 2.0, 10.0
    sphere = trimesh.creation.icosphere(subdivisions=6, radius=R_s)
    scene = Scene(model_of(sphere))
    cam = Camera(width=400, height=400, fx=600.0, fy=600.0, cx=199.5, cy=199.5)
    R, t = pose_looking_at_origin([0.0, -dist, 0.0])
    g = scene.render_geometry(cam, R, t)
    d_body = pixel_rays_cam(cam) @ R
    o_body = -R.T @ t
    # closed form ray–sphere: |o + s d|^2 = R^2, nearest root
    a = np.sum(d_body * d_body, -1)
    b = 2 * d_body @ o_body
    c = o_body @ o_body - R_s ** 2
    disc = b * b - 4 * a * c
    s = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
    # tessellation sag of the icosphere bounds the difference (distance face plane → sphere)
    tri = sphere.vertices[sphere.faces]
    sag = R_s - np.abs(np.einsum("ij,ij->i", sphere.face_normals, tri[:, 0])).min()
    core = g.mask & (disc > 0.3 * disc.max())  # away from the limb, where incidence is well defined
    err = np.abs(g.depth_m[core] - s[core])
    assert err.max() <= 2.5 * sag + 1e-5 * dist
    assert g.depth_m[200, 200] == pytest.approx(dist - R_s, abs=sag + 1e-6)
    # smooth shading normals vs the analytic sphere normal at the analytic hit point
    p = o_body + s[..., None] * d_body
    n_cam = (p / R_s) @ R.T
    assert angle_deg(g.normal_cam[core], n_cam[core]).max() < 0.05
    # silhouette area: disc of angular radius asin(R/d): r_px = f R / sqrt(d^2 - R^2)
    r_px = cam.fx * R_s / math.sqrt(dist ** 2 - R_s ** 2)
    r_px_inner = cam.fx * (R_s - sag) / math.sqrt(dist ** 2 - (R_s - sag) ** 2)
    area = g.mask.sum()
    perimeter = 2 * math.pi * r_px
    assert math.pi * r_px_inner ** 2 - perimeter <= area <= math.pi * r_px ** 2 + perimeter


def test_normals_face_the_camera_on_open_and_flipped_geometry():
    plate = trimesh.Trimesh(vertices=[[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], faces=[[0, 1, 2], [0, 2, 3]])
    flipped = plate.copy()
    flipped.faces = flipped.faces[:, ::-1]
    flipped.apply_translation([0, 0, 1.0])
    scene = Scene(model_of(plate, flipped))
    cam = Camera(width=200, height=200, fx=200.0, fy=200.0, cx=99.5, cy=99.5)
    for pos in ([0.3, 0.2, 5.0], [0.3, 0.2, -5.0]):
        R, t = pose_looking_at_origin(pos, up=(0, 1, 0))
        g = scene.render_geometry(cam, R, t, geometric_normal=True)
        rays = pixel_rays_cam(cam)
        m = g.mask
        assert m.sum() > 100
        assert np.all(np.sum(g.normal_cam[m] * rays[m], -1) < 0)
        assert np.all(np.sum(g.normal_geom_cam[m] * rays[m], -1) < 0)
        np.testing.assert_allclose(np.linalg.norm(g.normal_cam[m], axis=-1), 1.0, atol=1e-6)


# ------------------------------------------------------------------ brute-force reference
def moller_trumbore_reference(V, F, o, dirs):
    """Slow NumPy ray caster: nearest hit of every ray with every triangle (t, face) or (inf, -1)."""
    p0, p1, p2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = p1 - p0, p2 - p0
    t_best = np.full(len(dirs), np.inf)
    f_best = np.full(len(dirs), -1)
    for i0 in range(0, len(dirs), 512):
        d = dirs[i0:i0 + 512][:, None, :]
        pvec = np.cross(d, e2[None])
        det = np.einsum("fk,rfk->rf", e1, pvec)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            svec = o - p0
            u = np.einsum("fk,rfk->rf", svec, pvec) * inv
            q = np.cross(svec, e1)
            v = np.einsum("rk,fk->rf", d[:, 0], q) * inv
            t = np.einsum("fk,fk->f", e2, q)[None] * inv
        ok = (np.abs(det) > 1e-14) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        t = np.where(ok, t, np.inf)
        f_best[i0:i0 + 512] = np.where(np.isfinite(t.min(1)), t.argmin(1), -1)
        t_best[i0:i0 + 512] = t.min(1)
    return t_best, f_best


def small_assembly():
    box = trimesh.creation.box((1.0, 0.6, 0.4))
    cyl = trimesh.creation.cylinder(radius=0.25, height=1.2, sections=12)
    cyl.apply_translation([0.0, 0.0, 0.8])
    panel = trimesh.creation.box((2.0, 0.02, 0.5))
    panel.apply_translation([1.6, 0.0, 0.0])
    return model_of(box, cyl, panel, names=["bus", "mast", "panel"])


def test_embree_path_agrees_with_numpy_moller_trumbore():
    model = small_assembly()
    scene = Scene(model)
    cam = Camera(width=96, height=72, fx=90.0, fy=90.0, cx=47.5, cy=35.5)
    for pos in ([4.0, -3.0, 2.0], [-3.0, -4.0, -1.5], [0.5, 0.3, 5.0]):
        R, t = pose_looking_at_origin(pos)
        g = scene.render_geometry(cam, R, t)
        dirs = pixel_rays_cam(cam).reshape(-1, 3) @ R
        t_ref, f_ref = moller_trumbore_reference(scene.vertices, scene.faces, -R.T @ t, dirs)
        t_ref = t_ref.reshape(cam.height, cam.width)
        f_ref = f_ref.reshape(cam.height, cam.width)
        # misses agree except for rays within float32 of an outer edge
        both = np.isfinite(t_ref) & g.mask
        disagree = np.isfinite(t_ref) != g.mask
        assert disagree.sum() <= 2, disagree.sum()
        np.testing.assert_allclose(g.depth_m[both], t_ref[both], rtol=2e-7)
        same_face = g.face_index[both] == f_ref[both]
        # a different face only where two faces tie (shared edge): then the depth still agrees
        assert same_face.mean() > 0.98
        comp_ref = np.searchsorted(scene.face_offset, f_ref[both], side="right")
        assert np.mean(comp_ref == g.instance[both]) > 0.98


# ------------------------------------------------------------------ pose <-> pixels
def test_vertices_project_onto_their_component_and_depth_backprojects_onto_mesh():
    # subdivided so that most vertices lie inside faces, not only on silhouette corners
    base = small_assembly()
    model = TargetModel("test", tuple(Component(c.name, c.mesh.subdivide().subdivide(), c.material, c.semantic, 1.0)
                                      for c in base.components))
    scene = Scene(model)
    cam = Camera(width=640, height=480, fx=700.0, fy=700.0, cx=319.5, cy=239.5)
    rng = np.random.default_rng(3)
    for _ in range(3):
        pos = rng.normal(size=3)
        pos *= 6.0 / np.linalg.norm(pos)
        R, t = pose_looking_at_origin(pos)
        g = scene.render_geometry(cam, R, t)
        K = cam.K
        checked = 0
        for k, comp in enumerate(model.components):
            p_cam = comp.mesh.vertices @ R.T + t
            uvw = p_cam @ K.T
            uv = uvw[:, :2] / uvw[:, 2:]
            iu, iv = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
            inside = (iu >= 1) & (iu < cam.width - 1) & (iv >= 1) & (iv < cam.height - 1)
            for j in np.flatnonzero(inside):
                win = (slice(iv[j] - 1, iv[j] + 2), slice(iu[j] - 1, iu[j] + 2))
                depth_win = g.depth_m[win]
                if not np.any(np.abs(depth_win - p_cam[j, 2]) < 1e-3 * p_cam[j, 2]):
                    continue  # occluded (or on a silhouette): not visible
                assert (k + 1) in g.instance[win]
                checked += 1
        assert checked > 100
        # back-project every hit pixel and measure its distance to the mesh (trimesh proximity)
        v, u = np.nonzero(g.mask)
        sel = rng.choice(len(u), size=min(400, len(u)), replace=False)
        z = g.depth_m[v[sel], u[sel]].astype(float)
        p_cam = np.column_stack([(u[sel] - cam.cx) / cam.fx * z, (v[sel] - cam.cy) / cam.fy * z, z])
        p_body = (p_cam - t) @ R
        mesh = model.combined_mesh()
        dist = point_mesh_distance(p_body, np.asarray(mesh.vertices), np.asarray(mesh.faces))
        assert dist.max() < 1e-4 * np.linalg.norm(pos)


# ------------------------------------------------------------------ culling and stress
def test_culled_render_equals_full_frame_bit_for_bit():
    scene = Scene(small_assembly())
    cam = Camera(width=320, height=240, fx=300.0, fy=300.0, cx=159.5, cy=119.5)
    rng = np.random.default_rng(11)
    for _ in range(5):
        pos = rng.normal(size=3)
        pos *= rng.uniform(3.0, 30.0) / np.linalg.norm(pos)
        R, t = pose_looking_at_origin(pos)
        R = axis_angle([0, 0, 1.0], rng.uniform(-0.3, 0.3)) @ R  # target off-centre
        a = scene.render_geometry(cam, R, t, ray_distance=True, geometric_normal=True)
        b = scene.render_geometry(cam, R, t, cull=False, ray_distance=True, geometric_normal=True)
        assert a.cast_rect != (0, 0, cam.width, cam.height) or a.mask.mean() > 0.5
        for name in ("depth_m", "normal_cam", "normal_geom_cam", "instance", "face_index", "ray_distance_m"):
            assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name


def spread_parts():
    """Parts far apart with empty space between them, some flat (a single triangle, a panel
    of zero thickness), thin (a rod) or tiny: what the per-part culling polytopes
    (:func:`raytrace.scene._part_hulls`) must bound each, degenerate hulls included."""
    rod = trimesh.creation.cylinder(radius=0.01, height=6.0, sections=6)
    rod.apply_transform(trimesh.transformations.rotation_matrix(0.7, [1.0, 1.0, 0.0]))
    rod.apply_translation([3.0, 0.0, 0.0])
    tri = trimesh.Trimesh([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[0, 1, 2]])
    tri.apply_translation([-3.0, 2.0, 1.0])
    flat = trimesh.Trimesh([[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    flat.apply_translation([-2.0, -3.0, -1.0])
    speck = trimesh.creation.icosphere(subdivisions=0, radius=0.004)
    speck.apply_translation([0.5, 2.5, -2.0])
    return model_of(trimesh.creation.box((1.0, 0.6, 0.4)), rod, tri, flat, speck)


def test_part_culling_casts_a_fraction_and_loses_no_hit(monkeypatch):
    """The geometry pass casts only inside the images of the parts' bounding polytopes
    (raytrace._kernels.cull_mask): the same AOVs bit for bit as every pixel of the frame, on
    parts far apart (flat, thin, tiny), from near (polytopes straddling the camera's plane)
    to far, the target crossing the image's border; and the mask holds every hit of the full
    frame and far fewer pixels than the rectangle."""
    import raytrace._kernels as kernels
    import raytrace.scene as scene_module
    scene = Scene(spread_parts())
    if scene.direct is None:
        pytest.skip("no Embree 4 in the embreex wheel: the chunks cast the whole rectangle")
    masks = []
    real = kernels.cull_mask

    def spy(*args):
        real(*args)
        masks.append((args[6], args[7], args[-1].copy()))

    monkeypatch.setattr(kernels, "cull_mask", spy)
    cam = Camera(width=160, height=120, fx=150.0, fy=150.0, cx=79.5, cy=59.5)
    rng = np.random.default_rng(3)
    fractions = []
    for k in range(40):
        pos = rng.normal(size=3)
        pos *= rng.uniform(2.0, 60.0) / np.linalg.norm(pos)
        R, t = pose_looking_at_origin(pos)
        R = axis_angle(rng.normal(size=3), rng.uniform(0.0, 0.5)) @ R  # off-centre, across the border
        masks.clear()
        a = scene.render_geometry(cam, R, t, ray_distance=True, geometric_normal=True)
        b = scene.render_geometry(cam, R, t, cull=False, ray_distance=True, geometric_normal=True)
        for name in ("depth_m", "normal_cam", "normal_geom_cam", "instance", "face_index", "ray_distance_m"):
            assert np.array_equal(getattr(a, name).view(np.uint8), getattr(b, name).view(np.uint8)), (k, name)
        if masks:
            u0, v0, cast = masks[0]
            hit = b.mask[v0:v0 + cast.shape[0], u0:u0 + cast.shape[1]]
            assert b.mask.sum() == hit.sum() and np.all(cast[hit] == 1), k
            fractions.append(cast.mean())
    assert len(fractions) >= 20
    assert np.median(fractions) < 0.5  # parts far apart: most of the rectangle is empty space


def test_cull_mask_covers_the_projected_polygon():
    """raytrace._kernels.cull_mask against point-in-polygon of the projected hull (scipy's
    Delaunay): every pixel centre inside a polytope's image is marked, none farther than
    two pixels from it; one polytope at or behind the camera's plane marks everything."""
    from scipy.spatial import Delaunay, cKDTree

    from raytrace._kernels import cull_mask
    rng = np.random.default_rng(8)
    fx = fy = 40.0
    cx, cy = 31.5, 22.5
    u0, v0, w, h = 2, 1, 60, 44
    vv, uu = np.mgrid[v0:v0 + h, u0:u0 + w]
    centres = np.column_stack([uu.ravel(), vv.ravel()]).astype(float)
    for trial in range(30):
        groups = [rng.normal(size=(rng.integers(1, 12), 3)) * rng.uniform(0.05, 1.0) + [*rng.normal(size=2), 4.0]
                  for _ in range(rng.integers(1, 4))]
        if trial % 5 == 0:  # collinear points: a segment's image
            groups.append(np.outer(rng.uniform(-1, 1, 4), rng.normal(size=3)) + [0.0, 0.0, 3.0])
        P = np.concatenate(groups)
        ptr = np.cumsum([0] + [len(g) for g in groups]).astype(np.int64)
        cast = np.full((h, w), 7, np.uint8)
        cull_mask(P, ptr, fx, fy, cx, cy, u0, v0, w, h, 1e-9, cast)
        assert set(np.unique(cast)) <= {0, 1}
        uv_all = []
        for g in groups:
            uv = np.column_stack([fx * g[:, 0] / g[:, 2] + cx, fy * g[:, 1] / g[:, 2] + cy])
            uv_all.append(uv)
            if len(uv) >= 3 and np.linalg.matrix_rank(uv[1:] - uv[0], tol=1e-9) == 2:
                inside = Delaunay(uv).find_simplex(centres) >= 0
                assert np.all(cast.ravel()[inside] == 1), trial
        # nothing marked far from every polygon: at most a row above or below it and a pixel
        # beside it, √2 px
        marked = centres[cast.ravel() == 1]
        far = np.ones(len(marked), dtype=bool)
        for uv in uv_all:
            if len(uv) >= 3 and np.linalg.matrix_rank(uv[1:] - uv[0], tol=1e-9) == 2:
                far &= Delaunay(uv).find_simplex(marked) < 0
        edges = np.concatenate([np.concatenate([a + (b - a) * s for s in np.linspace(0, 1, 200)[:, None, None]])
                                for uv in uv_all for a, b in [(uv[i], uv[j]) for i in range(len(uv))
                                                                 for j in range(len(uv))]])
        d, _ = cKDTree(edges).query(marked[far])
        assert d.size == 0 or d.max() <= math.sqrt(2.0) + 0.02, trial
    P = np.array([[0.0, 0.0, 5.0], [1.0, 0.0, 5.0], [0.0, 1.0, -0.1]])
    cast = np.zeros((h, w), np.uint8)
    cull_mask(P, np.array([0, 3], np.int64), fx, fy, cx, cy, u0, v0, w, h, 1e-9, cast)
    assert cast.all()


def test_one_kernel_geometry_pass_equals_the_embreex_chunks_bit_for_bit(monkeypatch):
    """render_geometry casts, intersects and refines in one numba kernel that calls Embree
    (raytrace._kernels.cast_and_refine); the row chunks through embreex (the fallback, and an
    explicit thread count) give the same AOVs bit for bit, culled or full frame, on a built-in
    target (open and closed parts, thin rods) and the small assembly."""
    import raytrace._kernels as kernels
    from raytrace import presets
    from raytrace.targets import load_target
    if Scene(small_assembly()).direct is None:
        pytest.skip("no Embree 4 in the embreex wheel: the chunks are the only path")
    cam = Camera(width=320, height=240, fx=260.0, fy=280.0, cx=151.3, cy=127.9)
    rng = np.random.default_rng(5)
    ran = []
    for name in ("cast_and_refine", "refine_hits"):
        real = getattr(kernels, name)

        def spy(*a, _real=real, _name=name):
            ran.append(_name)
            return _real(*a)

        monkeypatch.setattr(kernels, name, spy)
    for model, far in ((small_assembly(), 30.0), (load_target("cassini"), 40.0)):
        scene = Scene(model)
        for _ in range(3):
            pos = rng.normal(size=3)
            pos *= rng.uniform(0.3, 1.0) * far / np.linalg.norm(pos)
            R, t = pose_looking_at_origin(pos)
            R = axis_angle([0, 0, 1.0], rng.uniform(-0.3, 0.3)) @ R
            frames = []
            for one_kernel, kw in ((True, {}), (True, {"cull": False}), (False, {}), (False, {"threads": 2})):
                monkeypatch.setattr(presets, "CAST_IN_ONE_KERNEL", one_kernel)
                ran.clear()
                frames.append(scene.render_geometry(cam, R, t, ray_distance=True, geometric_normal=True, **kw))
                # the path the switch chose ran: the one kernel, or the chunks' refinement
                assert set(ran) == {"cast_and_refine" if one_kernel else "refine_hits"}, (one_kernel, kw)
            assert frames[0].mask.any()
            for other in frames[1:]:
                for name in ("depth_m", "normal_cam", "normal_geom_cam", "instance", "face_index", "ray_distance_m"):
                    a, b = getattr(frames[0], name), getattr(other, name)
                    assert np.array_equal(a.view(np.uint8), b.view(np.uint8)), name


@pytest.mark.parametrize("dist", [1.0, 10_000.0])
def test_extreme_ranges(dist):
    scene = Scene(small_assembly())
    cam = Camera(width=256, height=192, fx=200.0, fy=200.0, cx=127.5, cy=95.5)
    if dist == 1.0:  # inside the hull: culling switches off, the frame is still exact
        R, t = pose_looking_at_origin([0.2, -0.25, 0.1])
        g = scene.render_geometry(cam, R, t)
        assert g.camera_inside_hull and g.cast_rect == (0, 0, 256, 192)
    else:
        cam = Camera(width=256, height=192, fx=2e5, fy=2e5, cx=127.5, cy=95.5)  # long lens
        R, t = pose_looking_at_origin([dist, -dist * 0.1, dist * 0.05])
        g = scene.render_geometry(cam, R, t)
        assert not g.camera_inside_hull and g.mask.sum() > 100
        z = g.depth_m[g.mask]
        assert np.all(np.abs(z - np.linalg.norm(t)) < 3.0)  # the assembly is ~3 m across
    assert np.all(np.isfinite(g.depth_m[g.mask])) and np.all(np.isinf(g.depth_m[~g.mask]))


def test_target_wholly_behind_the_camera():
    """Behind the camera there is nothing to see: an empty frame, visible fraction 0, culling
    on (not the "camera inside the hull" case, whose fraction is NaN)."""
    scene = Scene(small_assembly())
    cam = Camera(width=64, height=48, fx=60.0, fy=60.0, cx=31.5, cy=23.5)
    for z in (-30.0, -5000.0):
        g = scene.render_geometry(cam, np.eye(3), [0.0, 0.0, z])
        assert not g.camera_inside_hull and g.cast_rect == (0, 0, 0, 0)
        assert g.visible_fraction == 0.0 and not g.mask.any()


def test_one_pixel_and_large_images():
    scene = Scene(small_assembly())
    R, t = pose_looking_at_origin([0.0, -8.0, 0.0])
    g = scene.render_geometry(Camera(width=1, height=1, fx=10.0, fy=10.0, cx=0.0, cy=0.0), R, t)
    assert g.depth_m.shape == (1, 1) and g.instance[0, 0] == 1  # the bus is on the boresight
    big = Camera(width=4096, height=3072, fx=3000.0, fy=3000.0, cx=2047.5, cy=1535.5)
    g = scene.render_geometry(big, R, t)
    assert g.depth_m.shape == (3072, 4096) and g.mask.sum() > 10_000
    assert g.depth_m[1535, 2047] == pytest.approx(8.0 - 0.3, rel=1e-6)  # bus face at y = -0.3


def test_target_behind_camera_casts_nothing():
    scene = Scene(small_assembly())
    R, t = pose_looking_at_origin([0.0, -8.0, 0.0])
    g = scene.render_geometry(Camera(width=64, height=48, fx=50, fy=50, cx=31.5, cy=23.5), R, -t)
    assert g.mask.sum() == 0 and g.bbox_xyxy is None


def test_label_facts():
    scene = Scene(small_assembly())
    cam = Camera(width=320, height=240, fx=300.0, fy=300.0, cx=159.5, cy=119.5)
    R, t = pose_looking_at_origin([3.0, -5.0, 2.0])
    g = scene.render_geometry(cam, R, t)
    counts = g.pixel_counts
    assert counts.shape == (4,) and counts.sum() == cam.width * cam.height
    assert counts[0] == (~g.mask).sum() and np.all(counts[1:] > 0)
    rows, cols = np.nonzero(g.mask)
    assert g.bbox_xyxy == (cols.min(), rows.min(), cols.max(), rows.max())
    x, y, w, h = g.bbox_xywh
    assert (w, h) == (cols.max() - cols.min() + 1, rows.max() - rows.min() + 1)


def test_bad_inputs():
    scene = Scene(small_assembly())
    cam = Camera(width=8, height=8, fx=5, fy=5, cx=3.5, cy=3.5)
    with pytest.raises(ValueError, match="R_cam_from_body must be a rotation"):
        scene.render_geometry(cam, np.diag([1.0, 1.0, -1.0]), [0, 0, 5.0])
    with pytest.raises(ValueError, match="t_cam_m must be finite|must be finite"):
        scene.render_geometry(cam, np.eye(3), [0, 0, np.nan])
    with pytest.raises(ValueError, match="camera must be"):
        scene.render_geometry("cam", np.eye(3), [0, 0, 5.0])
    degenerate = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [2, 0, 0]], faces=[[0, 1, 2]], process=False)
    with pytest.raises(ValueError, match="zero-area triangle"):
        Scene(model_of(degenerate))
    for kwargs, match in [(dict(width=0), "width"), (dict(fx=-1.0), "fx"), (dict(cy=math.nan), "cy")]:
        with pytest.raises(ValueError, match=match):
            Camera(**kwargs)


def test_scene_pickles_without_embree():
    import pickle
    scene = Scene(small_assembly())
    R, t = pose_looking_at_origin([3.0, -5.0, 2.0])
    cam = Camera(width=64, height=48, fx=60, fy=60, cx=31.5, cy=23.5)
    a = scene.render_geometry(cam, R, t)
    clone = pickle.loads(pickle.dumps(scene))
    assert clone._embree is None
    b = clone.render_geometry(cam, R, t)
    assert np.array_equal(a.depth_m, b.depth_m) and np.array_equal(a.instance, b.instance)


def test_visible_fraction_and_semantic_map():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    model = TargetModel("s", (Component("ball", sphere, "white_paint", "dish", 1.0),))
    scene = Scene(model)
    cam = Camera(width=200, height=160, fx=200.0, fy=200.0, cx=99.5, cy=79.5)
    R = np.eye(3)
    assert scene.render_geometry(cam, R, [0, 0, 10.0]).visible_fraction == 1.0
    # centre projected onto the left image border (u = -0.5): half the disc is inside
    z = 10.0
    x = (-0.5 - cam.cx) * z / cam.fx
    g = scene.render_geometry(cam, R, [x, 0.0, z])
    r_px = cam.fx * 1.0 / math.sqrt(z * z - 1.0)
    assert g.visible_fraction == pytest.approx(0.5, abs=2 * (2 * r_px) / (math.pi * r_px ** 2))
    # a silhouette much larger than the image: counted on a coarser grid, still close
    g = scene.render_geometry(cam, R, [-1.0, 0.0, 1.3])
    assert 0.0 < g.visible_fraction < 0.2
    exact_total = g.mask.sum() + scene._pixels_outside_image(
        cam, R, np.array([-1.0, 0.0, 1.3]), scene.projected_rect(cam, R, [-1.0, 0.0, 1.3]), max_rays=10**8)
    # the off-image part is counted on a coarser grid here (silhouette ~20x the image): an estimate
    assert g.visible_fraction == pytest.approx(g.mask.sum() / exact_total, rel=0.03)
    # independent: the same silhouette on a sensor 5x larger (same pixel grid, centred the same way)
    big = Camera(width=1000, height=800, fx=cam.fx, fy=cam.fy, cx=cam.cx + 400, cy=cam.cy + 320)
    gb = scene.render_geometry(big, R, [-1.0, 0.0, 1.3], visible_fraction=False)
    if gb.mask[0].sum() + gb.mask[-1].sum() + gb.mask[:, 0].sum() + gb.mask[:, -1].sum() == 0:
        assert g.visible_fraction == pytest.approx(g.mask.sum() / gb.mask.sum(), rel=0.02)
    assert scene.render_geometry(cam, R, [50.0, 0.0, 10.0]).visible_fraction == 0.0  # out of view
    assert math.isnan(scene.render_geometry(cam, R, [0.0, 0.0, 0.5]).visible_fraction)  # inside the ball
    g = scene.render_geometry(cam, R, [0, 0, 10.0])
    from raytrace.model import SEMANTIC_CLASSES
    assert set(np.unique(g.semantic)) == {0, SEMANTIC_CLASSES.index("dish") + 1}
    assert np.array_equal(g.semantic > 0, g.mask)


def test_crease_angle_is_per_component():
    # the same 12-sided cylinder twice: crease 0 → faceted (shading = flat normal), default → smooth
    cyl = trimesh.creation.cylinder(radius=1.0, height=2.0, sections=12)
    faceted, smooth = cyl.copy(), cyl.copy()
    faceted.apply_translation([-1.5, 0, 0])
    smooth.apply_translation([1.5, 0, 0])
    model = TargetModel("c", (Component("faceted", faceted, "white_paint", "bus", 1.0, crease_angle_rad=0.0),
                              Component("smooth", smooth, "white_paint", "bus", 1.0)))
    cam = Camera(width=320, height=160, fx=150.0, fy=150.0, cx=159.5, cy=79.5)
    R, t = pose_looking_at_origin([0.0, -10.0, 0.3])
    g = Scene(model).render_geometry(cam, R, t, geometric_normal=True)
    side = g.mask & (np.abs(g.normal_geom_cam @ (R @ [0, 0, 1.0])) < 0.5)  # cylinder walls, not the caps
    gap = np.zeros(g.mask.shape)
    gap[g.mask] = angle_deg(g.normal_cam[g.mask], g.normal_geom_cam[g.mask])
    f, s = side & (g.instance == 1), side & (g.instance == 2)
    assert f.sum() > 500 and s.sum() > 500
    assert gap[f].max() < 1e-3  # flat shading on the faceted copy
    assert np.percentile(gap[s], 90) > 3.0  # interpolated across the 30° facets on the smooth one
    assert gap[s].max() < 15.0 + 1e-3  # never beyond half a facet
