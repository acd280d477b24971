"""`raytrace._edges.edge_pixels` against the rule it implements, written out in NumPy.

The kernel decides which pixels ``fast`` and ``balanced`` anti-alias. It runs over row slices
with a one-pixel margin and special cases at the image's borders, so the reference here is the
plain rule: a pixel inside ``rect`` is an edge pixel if one of its 4-neighbours inside the image
has another id or another Earth flag, or — for target pixels — another lit flag, a normal whose
dot product with the pixel's is below 0.9, or a depth more than 3 % of the pixel's away.
"""

import numpy as np
import pytest

from raytrace._edges import edge_pixels


def _reference(inst, lit, normal, depth, earth, rect):
    H, W = inst.shape
    u0, v0, u1, v1 = rect
    flag = np.zeros((H, W), dtype=bool)
    for dv, du in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        # pixel (v, u) against its neighbour (v + dv, u + du), where that is in the image
        vs = slice(max(0, -dv), H - max(0, dv))
        us = slice(max(0, -du), W - max(0, du))
        vn = slice(max(0, dv), H + min(0, dv))
        un = slice(max(0, du), W + min(0, du))
        c_i, n_i = inst[vs, us], inst[vn, un]
        differs = (c_i != n_i) | (earth[vs, us] != earth[vn, un])
        dot = (normal[vs, us] * normal[vn, un]).sum(axis=-1)
        shading = ((lit[vs, us] != lit[vn, un]) | (dot < 0.9)
                   | (np.abs(depth[vn, un] - depth[vs, us]) > 0.03 * depth[vs, us]))
        flag[vs, us] |= differs | ((c_i != 0) & shading)
    out = np.zeros((H, W), dtype=bool)
    out[v0:v1, u0:u1] = flag[v0:v1, u0:u1]
    return out


def _scene(rng, H, W):
    """Blocky ids (so that neighbours agree often), an Earth disc, shadows, a few creases and
    depth steps on unit normals."""
    inst = np.zeros((H, W), dtype=np.uint16)
    for _ in range(6):
        v, u = rng.integers(0, H), rng.integers(0, W)
        inst[v:v + rng.integers(1, H // 2 + 2), u:u + rng.integers(1, W // 2 + 2)] = rng.integers(1, 4)
    # and the target across all four borders, where the kernel has its special cases
    inst[: H // 2 + 1, : W // 3 + 1] = 1
    inst[H // 3:, -(W // 3 + 1):] = 2
    yy, xx = np.mgrid[0:H, 0:W]
    earth = (yy - rng.uniform(0, H)) ** 2 + (xx - rng.uniform(0, W)) ** 2 < rng.uniform(0.1, 1.0) * H * W
    lit = rng.random((H, W)) < 0.9
    normal = np.zeros((H, W, 3), dtype=np.float32)
    normal[..., 2] = 1.0
    tilt = rng.random((H, W)) < 0.05
    normal[tilt] = [0.6, 0.0, 0.8]
    depth = np.full((H, W), 10.0, dtype=np.float32)
    depth[rng.random((H, W)) < 0.05] = rng.choice([10.2, 10.5, 9.6])
    lit[inst == 0] = False
    return inst, lit, normal, depth, earth


@pytest.mark.parametrize("H, W", [(1, 1), (1, 7), (7, 1), (2, 2), (37, 53), (64, 129)])
def test_edge_pixels_match_the_rule(H, W):
    rng = np.random.default_rng(H * 1000 + W)
    inst, lit, normal, depth, earth = _scene(rng, H, W)
    rects = [(0, 0, W, H), (0, 0, 0, 0), (W, H, W, H)]
    for _ in range(30):
        u = np.sort(rng.integers(0, W + 1, 2))
        v = np.sort(rng.integers(0, H + 1, 2))
        rects.append((u[0], v[0], u[1], v[1]))
        rects.append((0, v[0], W, v[1]))
        rects.append((u[0], 0, u[1], H))
    for rect in rects:
        out = np.zeros((H, W), dtype=bool)
        edge_pixels(inst, lit, normal, depth, earth, np.array(rect, dtype=np.int64), out)
        np.testing.assert_array_equal(out, _reference(inst, lit, normal, depth, earth, rect), err_msg=str(rect))


def test_edge_pixels_flags_each_cause():
    """One cause at a time on a uniform target: both pixels on either side of the change."""
    H, W = 9, 11
    for cause in ("id", "earth", "lit", "normal", "depth"):
        inst = np.ones((H, W), dtype=np.uint16)
        lit = np.ones((H, W), dtype=bool)
        normal = np.zeros((H, W, 3), dtype=np.float32)
        normal[..., 2] = 1.0
        depth = np.full((H, W), 5.0, dtype=np.float32)
        earth = np.zeros((H, W), dtype=bool)
        if cause == "id":
            inst[:, 6:] = 2
        elif cause == "earth":
            earth[:, 6:] = True
        elif cause == "lit":
            lit[:, 6:] = False
        elif cause == "normal":
            normal[:, 6:] = [0.5, 0.0, np.sqrt(0.75)]  # 30° apart
        else:
            depth[:, 6:] = 5.2  # a 4 % step
        out = np.zeros((H, W), dtype=bool)
        edge_pixels(inst, lit, normal, depth, earth, np.array([0, 0, W, H]), out)
        expected = np.zeros((H, W), dtype=bool)
        expected[:, 5:7] = True
        np.testing.assert_array_equal(out, expected, err_msg=cause)
    # below the thresholds: 20° apart (dot 0.94), a 2 % step: no edge
    normal[:, 6:] = [np.sin(np.radians(20)), 0.0, np.cos(np.radians(20))]
    depth[:, 6:] = 5.1
    out = np.zeros((H, W), dtype=bool)
    edge_pixels(inst, lit, normal, depth, earth, np.array([0, 0, W, H]), out)
    assert not out.any()
