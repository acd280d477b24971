"""Keypoints: the default set (farthest-point sampling of the hull against a brute-force
implementation), the user file's checks, pixel positions against OpenCV's projection, and the
four states against closed-form answers on a box and against the depth image of a target."""

import itertools
import json
import math

import cv2
import numpy as np
import pytest
import trimesh

from raytrace.camera import Camera
from raytrace.keypoints import (default_keypoints, farthest_point_order, frame_keypoints, keypoint_states,
                                keypoints_document, read_keypoints)
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene
from raytrace.targets import BUILTIN_TARGETS, load_target


def _brute_fps(P, n, start):
    """Farthest-point sampling spelled out: each step scans every unchosen point and every chosen one."""
    chosen = [start]
    while len(chosen) < n:
        best, best_d = None, -1.0
        for i in range(len(P)):
            if i in chosen:
                continue
            d = min(math.dist(P[i], P[j]) for j in chosen)
            if d > best_d:
                best, best_d = i, d
        chosen.append(best)
    return chosen


@pytest.mark.parametrize("seed", range(5))
def test_farthest_point_order_is_the_greedy_max_min_choice(seed):
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(60, 3)) * [3.0, 1.0, 0.5]
    start = int(rng.integers(60))
    n = int(rng.integers(2, 20))
    assert farthest_point_order(P, n, start).tolist() == _brute_fps(P.tolist(), n, start)


def _box_model(extents=(2.0, 2.0, 2.0), name="box"):
    return TargetModel(name, (Component("bus", trimesh.creation.box(extents), "white_paint", "bus", 1.0),))


def test_default_keypoints_of_a_box_are_its_corners_whatever_the_vertex_order():
    model = _box_model((4.0, 2.0, 1.0))
    names, P = default_keypoints(model)  # 11 asked, the box's hull has 8 vertices
    corners = np.array(list(itertools.product((-2, 2), (-1, 1), (-0.5, 0.5))), dtype=float)
    assert names == [f"kp{k:02d}" for k in range(8)]
    assert sorted(map(tuple, P)) == sorted(map(tuple, corners))
    # the first: the corner farthest from the centroid (all tie: the lexicographically smallest)
    assert P[0].tolist() == [-2.0, -1.0, -0.5]
    # the second: the corner farthest from it
    assert P[1].tolist() == [2.0, 1.0, 0.5]
    mesh = model.components[0].mesh
    rng = np.random.default_rng(1)
    perm = rng.permutation(len(mesh.vertices))
    inv = np.argsort(perm)
    shuffled = trimesh.Trimesh(mesh.vertices[perm], inv[mesh.faces], process=False)
    _, P2 = default_keypoints(TargetModel("box", (Component("bus", shuffled, "white_paint", "bus", 1.0),)), n=6)
    np.testing.assert_array_equal(P2, P[:6])


@pytest.mark.parametrize("target", BUILTIN_TARGETS)
def test_default_keypoints_of_the_builtin_targets_spread_over_their_hull(target):
    from scipy.spatial import ConvexHull
    model = load_target(target)
    names, P = default_keypoints(model)
    assert len(names) == len(P) == 11 and len(set(names)) == 11
    V = np.concatenate([c.mesh.vertices for c in model.components])
    hull = ConvexHull(V)
    # every point is a mesh vertex on the hull's boundary
    assert (np.abs(V[None] - P[:, None]).max(axis=2).min(axis=1) == 0).all()
    assert (hull.equations[:, :3] @ P.T + hull.equations[:, 3:]).max(axis=0).max() > -1e-9
    HV = V[hull.vertices]
    diameter = max(np.linalg.norm(HV[:, None] - HV[None], axis=2).max(), 1e-9)
    d = np.linalg.norm(P[:, None] - P[None], axis=2)
    min_pair = d[np.triu_indices(len(P), 1)].min()
    # farthest-point sampling's covering bound: every hull vertex lies within the last chosen
    # point's distance of the set, which is the set's smallest pairwise distance
    cover = np.linalg.norm(HV[:, None] - P[None], axis=2).min(axis=1).max()
    assert cover <= min_pair + 1e-9
    assert min_pair > 0.05 * diameter, (target, min_pair / diameter)  # measured: 0.078 (Tiangong) to 0.22


def test_default_keypoints_of_a_large_mesh_come_from_one_vertex_per_grid_cell(monkeypatch):
    """Beyond HULL_MAX_POINTS vertices: still mesh vertices, on the hull within a grid cell, the
    same whatever the vertex order, and spread as the exact hull's sampling."""
    from raytrace import keypoints
    mesh = trimesh.creation.icosphere(subdivisions=4)  # 2562 vertices, all on the hull
    model = TargetModel("ball", (Component("ball", mesh, "white_paint", "bus", 1.0),))
    _, exact = default_keypoints(model, n=16)
    monkeypatch.setattr(keypoints, "HULL_MAX_POINTS", 1000)
    calls = []
    grid = keypoints._grid_representatives
    monkeypatch.setattr(keypoints, "_grid_representatives", lambda V: calls.append(len(V)) or grid(V, cells=16))
    _, P = default_keypoints(model, n=16)
    assert calls == [len(mesh.vertices)]
    V = np.asarray(mesh.vertices)
    assert (np.abs(V[None] - P[:, None]).max(axis=2).min(axis=1) == 0).all()
    perm = np.random.default_rng(2).permutation(len(V))
    shuffled = trimesh.Trimesh(V[perm], np.argsort(perm)[mesh.faces], process=False)
    _, P2 = default_keypoints(TargetModel("ball", (Component("ball", shuffled, "white_paint", "bus", 1.0),)), n=16)
    np.testing.assert_array_equal(P2, P)

    def min_pair(Q):
        d = np.linalg.norm(Q[:, None] - Q[None], axis=2)
        return d[np.triu_indices(len(Q), 1)].min()

    assert min_pair(P) > 0.9 * min_pair(exact)


def test_default_keypoints_count_is_checked():
    for bad in (3, 65, 4.0, True):
        with pytest.raises(ValueError, match=r"^n must be an integer in \[4, 64\]"):
            default_keypoints(_box_model(), n=bad)


# --------------------------------------------------------------------------- the user's file
def test_read_keypoints_takes_the_schema_and_a_plain_list(tmp_path):
    pts = [[0.0, 1.0, 2.0], [1, 0, 0], [-1.5, 0.25, 3]]
    doc = keypoints_document(["a", "b", "c"], pts, "hand-picked")
    f = tmp_path / "kp.json"
    f.write_text(json.dumps(doc))
    names, P, source = read_keypoints(f)
    assert names == ["a", "b", "c"] and source == "hand-picked"
    np.testing.assert_array_equal(P, pts)
    f.write_text(json.dumps(pts))
    names, P, source = read_keypoints(f)
    assert names == ["kp00", "kp01", "kp02"] and source is None
    np.testing.assert_array_equal(P, pts)


@pytest.mark.parametrize("content, match", [
    ('{"a": 1}', "unknown key 'a'"),
    ('"x"', "must be a JSON object with points_body_m"),
    ('{"names": ["a"]}', "lacks points_body_m"),
    ('[]', "must hold 1 to 256 points, got 0"),
    (json.dumps([[0, 0, k] for k in range(257)]), "must hold 1 to 256 points, got 257"),
    ('[[0, 0, NaN]]', r"point 0 must be \[x, y, z\], three finite numbers"),
    ('[[0, 0, 1e999]]', r"point 0 must be \[x, y, z\]"),
    ('[[0, 0]]', r"point 0 must be \[x, y, z\]"),
    ('[[0, 0, "1"]]', r"point 0 must be \[x, y, z\]"),
    ('[[0, 0, 1], [1, 1, 1], [0, 0, 1]]', r"point 2 repeats point 0"),
    ('{"points_body_m": [[0, 0, 1], [1, 1, 1]], "names": ["a", "a"]}', "names must be unique, repeated: 'a'"),
    ('{"points_body_m": [[0, 0, 1], [1, 1, 1]], "names": ["a"]}', "names must be a list of 2 non-empty strings"),
    ('{"points_body_m": [[0, 0, 1]], "unit": "mm"}', "unit must be 'm'"),
    ('{"points_body_m": [[0, 0, 1]], "frame": "camera"}', "frame must be 'body'"),
    ('{"points_body_m": [[0, 0, 1]], "source": 3}', "source must be a string"),
    ('[[0, 0, 1]', "is not UTF-8 JSON"),
])
def test_read_keypoints_bad_file_is_one_line(tmp_path, content, match):
    f = tmp_path / "kp.json"
    f.write_text(content)
    with pytest.raises(ValueError, match=match) as info:
        read_keypoints(f)
    assert "\n" not in str(info.value) and str(info.value).startswith(str(f))


def test_read_keypoints_missing_file_is_one_line(tmp_path):
    with pytest.raises(ValueError, match="cannot read it"):
        read_keypoints(tmp_path / "none.json")


# --------------------------------------------------------------------------- states on a box
CAM = Camera(160, 120, 150.0, 140.0, 81.3, 57.9)
R_IDENT = np.eye(3)
T_BOX = np.array([0.0, 0.0, 10.0])  # the optical centre at body (0, 0, -10), looking along +z


def _box_scene():
    return Scene(_box_model())


def _inward(corner, sun):
    """Closed form: a box corner is shaded by the box itself iff the Sun's direction points into
    the box's interior cone at that corner (every component towards the box's inside)."""
    return all(np.sign(s) == -np.sign(c) and s != 0 for c, s in zip(corner, sun))


def test_states_of_box_corners_match_the_closed_form():
    scene = _box_scene()
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
    for sun in ([0.0, 0.0, -1.0], [-0.3, -0.2, 1.0], [0.4, -0.5, 0.6], [0.2, 0.7, -0.3]):
        uv, states = keypoint_states(scene, CAM, R_IDENT, T_BOX, corners, sun)
        for c, st in zip(corners, states):
            if c[2] > 0:  # the back face: the segment from (0, 0, -10) to it crosses the front face
                assert st == "occluded", (c, sun)
            else:
                assert st == ("shadowed" if _inward(c, sun) else "visible"), (c, sun, st)
    # Earth's shadow: below half the solar disc every point in view is shadowed
    _, states = keypoint_states(scene, CAM, R_IDENT, T_BOX, corners, [0.0, 0.0, -1.0], shadow_fraction=0.49)
    assert [s for c, s in zip(corners, states) if c[2] < 0] == ["shadowed"] * 4
    _, states = keypoint_states(scene, CAM, R_IDENT, T_BOX, corners, [0.0, 0.0, -1.0], shadow_fraction=0.5)
    assert [s for c, s in zip(corners, states) if c[2] < 0] == ["visible"] * 4


def test_points_on_inside_and_just_outside_the_surface():
    scene = _box_scene()
    eps = 1e-3  # 10x the tolerance (1e-4 of the bounding radius sqrt(3))
    P = np.array([[0.2, 0.1, -1.0], [0.2, 0.1, -1.0 - eps], [0.2, 0.1, -1.0 + eps],  # front face: on, out, in
                  [1.0, 0.3, -0.2], [1.0 + eps, 0.3, -0.2], [1.0 - eps, 0.3, -0.2]])  # side face x = 1
    _, states = keypoint_states(scene, CAM, R_IDENT, T_BOX, P, [0.0, 0.0, -1.0])
    # the side face x = 1 is seen from (0, 0, -10)? no: the camera is at x = 0 < 1, it sees only the front face
    assert states == ["visible", "visible", "occluded", "occluded", "occluded", "occluded"]
    # seen from x > 1 the side face's points are visible, its inner one not; the Sun along +x lights them
    R = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # camera z along body -x
    t = -R @ np.array([10.0, 0.0, 0.0])  # optical centre at body (10, 0, 0)
    _, states = keypoint_states(scene, CAM, R, t, P[3:], [1.0, 0.1, 0.0])
    assert states == ["visible", "visible", "occluded"]
    _, states = keypoint_states(scene, CAM, R, t, P[3:], [-1.0, 0.1, 0.0])  # Sun behind the box
    assert states == ["shadowed", "shadowed", "occluded"]


def test_projection_matches_opencv_and_outside_points():
    scene = _box_scene()
    rng = np.random.default_rng(3)
    rvec = rng.normal(size=3) * 0.2
    R = cv2.Rodrigues(rvec)[0]
    t = np.array([0.1, -0.2, 9.0])
    P = rng.uniform(-1, 1, size=(20, 3))
    uv, _ = keypoint_states(scene, CAM, R, t, P, [0, 0, -1.0])
    ref, _ = cv2.projectPoints(P, rvec, t, CAM.K, np.zeros(5))
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), rtol=0, atol=1e-9)
    # off the image: beyond each edge by a hair, behind and at the optical centre
    W, H = CAM.width, CAM.height

    def body_at(u, v, z=10.0):  # the body point whose pixel is (u, v) at depth z (identity rotation)
        return np.array([(u - CAM.cx) / CAM.fx * z, (v - CAM.cy) / CAM.fy * z, z]) - T_BOX

    Q = np.array([body_at(-0.5, 10), body_at(-0.5 - 1e-6, 10), body_at(W - 0.5 - 1e-6, 10), body_at(W - 0.5, 10),
                  body_at(10, -0.5), body_at(10, -0.5 - 1e-6), body_at(10, H - 0.5 - 1e-6), body_at(10, H - 0.5),
                  [0.0, 0.0, -12.0], [0.0, 0.0, -10.0]])
    d = frame_keypoints(scene, CAM, R_IDENT, T_BOX, Q, {"sun_dir_body": [0, 0, -1.0], "shadow_fraction": 1.0})
    inside = [True, False, True, False, True, False, True, False, False, False]
    assert [s != "outside" for s in d["keypoints_state"]] == inside
    assert d["keypoints_px"][-2:] == [None, None]
    assert all(p is not None and len(p) == 2 for p in d["keypoints_px"][:-2])
    json.dumps(d, allow_nan=False)


# --------------------------------------------------------------------------- states against a depth image
def test_occlusion_agrees_with_the_depth_image_on_clear_cases():
    """A point whose 3 × 3 pixel neighbourhood in the rendered depth image is entirely nearer than
    it by a margin is hidden; one whose neighbourhood is nowhere nearer (beyond a pixel's depth
    spread) is seen. The others (a part smaller than a pixel in front, a surface sloping towards
    the camera) are no clear case."""
    model = load_target("icesat")
    scene = Scene(model)
    _, P = default_keypoints(model, n=32)
    radius = model.bounding_radius_m
    cam = Camera(200, 150, 260.0, 260.0, 99.5, 74.5)
    rng = np.random.default_rng(0)
    counts = {"seen": 0, "hidden": 0}
    for _ in range(6):
        z_axis = rng.normal(size=3)
        z_axis /= np.linalg.norm(z_axis)  # the boresight, in the body frame
        x_axis = np.cross(z_axis, [0.3, 0.5, 0.8])
        x_axis /= np.linalg.norm(x_axis)
        R = np.array([x_axis, np.cross(z_axis, x_axis), z_axis])  # rows: camera axes in the body frame
        t = np.array([0.0, 0.0, 3.0 * radius])  # the target's centre 3 radii ahead
        depth = scene.render_geometry(cam, R, t).depth_m
        _, states = keypoint_states(scene, cam, R, t, P, -z_axis)
        z = P @ R[2] + t[2]
        uv = cam.project(P @ R.T + t)
        for (u, v), zk, st in zip(uv, z, states):
            iu, iv = int(round(u)), int(round(v))
            if not (1 <= iu < cam.width - 1 and 1 <= iv < cam.height - 1):
                continue
            patch = depth[iv - 1:iv + 2, iu - 1:iu + 2]
            if (patch < zk - 0.05 * radius).all():  # a surface well in front all around
                assert st == "occluded"
                counts["hidden"] += 1
            elif (patch > zk - 0.005 * radius).all():  # nothing in front (a pixel spans ~0.012 radius)
                assert st != "occluded"
                counts["seen"] += 1
    assert counts["seen"] >= 30 and counts["hidden"] >= 30, counts  # measured: 50 and 54


def test_states_bad_input_is_one_line():
    scene = _box_scene()
    with pytest.raises(ValueError, match=r"^points_body_m must be an \(N, 3\) array of finite numbers"):
        keypoint_states(scene, CAM, R_IDENT, T_BOX, [[0.0, 0.0, math.nan]], [0, 0, -1.0])
    with pytest.raises(ValueError, match=r"^points_body_m must be an \(N, 3\)"):
        keypoint_states(scene, CAM, R_IDENT, T_BOX, [0.0, 0.0, 1.0], [0, 0, -1.0])
    with pytest.raises(ValueError, match="^sun_dir_body must be a finite non-zero vector"):
        keypoint_states(scene, CAM, R_IDENT, T_BOX, [[0.0, 0.0, 1.0]], [0, 0, 0])
