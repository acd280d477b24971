"""Tests for the procedural Tiangong (T configuration) target.

Published figures below are typed from the sources cited in the module docstring
(Xinhua/CMSA press material), not from the model's output.
"""

from __future__ import annotations

import re
import time

import numpy as np
import pytest

from raytrace.model import MATERIALS, SEMANTIC_CLASSES
from raytrace.targets.tiangong import build

# --- published dimensions ------------------------------------------------------------------
TIANHE_LENGTH_M = 16.6          # Xinhua 2021-04-29
TIANHE_MAX_DIAMETER_M = 4.2     # Xinhua 2021-04-29
TIANHE_SMALL_DIAMETER_M = 2.8   # small cylinder section
NODE_DIAMETER_M = 2.8           # spherical docking hub
TIANHE_MASS_KG = 22_500.0       # Xinhua 2021-04-29
TIANHE_WING_LENGTH_M = 11.0     # two 11 m x 4.6 m arrays
TIANHE_WING_WIDTH_M = 4.6
LAB_LENGTH_M = 17.9             # Wentian/Mengtian, Xinhua / China Daily 2022
LAB_DIAMETER_M = 4.2
LAB_MASS_KG = 23_000.0
LAB_WING_SPAN_M = 55.0          # "wingspan of over 55 metres" (CMSA 2022-08)
LAB_WING_AREA_M2 = 110.0        # "a single wing spreads to about 110 square metres"
CROSSBAR_M = NODE_DIAMETER_M + 2 * LAB_LENGTH_M   # hub + two labs end to end
TOL = 0.10


def _close(value, published, tol=TOL):
    return abs(value - published) <= tol * published


@pytest.fixture(scope="module")
def model():
    return build()


def _comps(model, pattern):
    rx = re.compile(pattern)
    return [c for c in model.components if rx.fullmatch(c.name)]


def _extent(comps):
    lo = np.min([c.mesh.bounds[0] for c in comps], axis=0)
    hi = np.max([c.mesh.bounds[1] for c in comps], axis=0)
    return hi - lo


def _volume_centroid(vertices, faces):
    """Volume and centroid of a closed mesh from signed tetrahedra about the origin."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    vol6 = np.einsum("ij,ij->i", a, np.cross(b, c))
    vol = vol6.sum() / 6.0
    centroid = ((a + b + c) * vol6[:, None]).sum(axis=0) / (24.0 * vol)
    return vol, centroid


# --- identity, materials, hygiene ------------------------------------------------------------

def test_names_materials_semantics(model):
    names = [c.name for c in model.components]
    assert len(names) == len(set(names))
    assert 10 <= len(names) <= 40
    for c in model.components:
        assert re.fullmatch(r"[a-z][a-z0-9_]*", c.name), c.name
        assert c.material in MATERIALS
        assert c.semantic in SEMANTIC_CLASSES
        assert c.mass_kg >= 0.0


def test_expected_parts_present(model):
    names = set(model.component_names)
    for required in ("tianhe_node", "tianhe_small_cylinder", "tianhe_large_cylinder",
                     "tianhe_forward_port", "tianhe_nadir_port", "tianhe_zenith_hatch",
                     "tianhe_aft_port", "wentian_wing_fwd", "wentian_wing_aft",
                     "mengtian_wing_fwd", "mengtian_wing_aft", "wentian_airlock_cabin",
                     "mengtian_exposed_platform"):
        assert required in names
    wings = _comps(model, r".*_wing_(fwd|aft|port|stbd)")
    assert len(wings) == 6
    assert all(c.material == "solar_cell" and c.semantic == "solar_panel" for c in wings)
    radiators = _comps(model, r".*_radiators")
    assert radiators and all(c.semantic == "radiator" for c in radiators)


def test_mesh_hygiene(model):
    for c in model.components:
        m = c.mesh
        assert len(m.faces) > 0
        assert np.all(np.isfinite(m.vertices)), c.name
        assert m.area_faces.min() > 1e-10, c.name
        key = np.sort(m.faces, axis=1)
        assert len(np.unique(key, axis=0)) == len(key), f"{c.name}: duplicate faces"
        assert m.is_watertight, c.name
        assert m.is_winding_consistent, c.name
        vol, _ = _volume_centroid(m.vertices, m.faces)
        assert vol > 0.0, f"{c.name}: inward winding"


def test_triangle_count(model):
    assert 3_000 <= model.n_triangles <= 150_000


def test_deterministic_and_fast():
    t0 = time.perf_counter()
    a = build()
    elapsed = time.perf_counter() - t0
    b = build()
    assert elapsed < 2.0
    assert a.component_names == b.component_names
    for ca, cb in zip(a.components, b.components):
        assert ca.mesh.vertices.tobytes() == cb.mesh.vertices.tobytes()
        assert ca.mesh.faces.tobytes() == cb.mesh.faces.tobytes()


# --- mass properties ---------------------------------------------------------------------------

def test_centre_of_mass_at_origin(model):
    total, moment = 0.0, np.zeros(3)
    for c in model.components:
        if c.mass_kg > 0:
            _, centroid = _volume_centroid(c.mesh.vertices, c.mesh.faces)
            total += c.mass_kg
            moment += c.mass_kg * centroid
    assert np.linalg.norm(moment / total) < 1e-6


def test_module_masses(model):
    for prefix, published in (("tianhe", TIANHE_MASS_KG), ("wentian", LAB_MASS_KG),
                              ("mengtian", LAB_MASS_KG)):
        mass = sum(c.mass_kg for c in _comps(model, prefix + r"_.*"))
        assert _close(mass, published, 0.02), (prefix, mass)


# --- overall and part dimensions ---------------------------------------------------------------

def test_overall_extents(model):
    ext = model.bounds_m[1] - model.bounds_m[0]
    assert _close(ext[0], LAB_WING_SPAN_M)                  # x: lab wings tip to tip
    assert _close(ext[1], CROSSBAR_M)                       # y: the crossbar of the T
    assert TIANHE_MAX_DIAMETER_M <= ext[2] <= 1.5 * TIANHE_MAX_DIAMETER_M   # thin in z


def test_bounding_radius(model):
    expected = np.hypot(LAB_WING_SPAN_M / 2, CROSSBAR_M / 2)
    assert 0.9 * expected <= model.bounding_radius_m <= 1.15 * expected


def test_tianhe_dimensions(model):
    body = _comps(model, r"tianhe_(?!wing).*")
    ext = _extent(body)
    assert _close(ext[0], TIANHE_LENGTH_M)
    large = _extent(_comps(model, "tianhe_large_cylinder"))
    assert _close(large[1], TIANHE_MAX_DIAMETER_M) and _close(large[2], TIANHE_MAX_DIAMETER_M)
    small = _extent(_comps(model, "tianhe_small_cylinder"))
    assert _close(small[1], TIANHE_SMALL_DIAMETER_M)
    node = _extent(_comps(model, "tianhe_node"))
    assert np.all(np.abs(node - NODE_DIAMETER_M) <= TOL * NODE_DIAMETER_M)


def test_tianhe_wings(model):
    for side in ("port", "stbd"):
        ext = _extent(_comps(model, f"tianhe_wing_{side}"))
        assert _close(ext[1], TIANHE_WING_LENGTH_M)          # extends along y
        assert _close(ext[0], TIANHE_WING_WIDTH_M)
        assert ext[2] < 0.06                                  # thin flexible blanket


@pytest.mark.parametrize("lab,sign", [("wentian", -1.0), ("mengtian", 1.0)])
def test_lab_dimensions_and_placement(model, lab, sign):
    body = _comps(model, lab + r"_(?!wing|radiators|small_arm|exposed|eva|cargo).*")
    ext = _extent(body)
    assert _close(ext[1], LAB_LENGTH_M)                       # lab axis along y
    assert _close(ext[0], LAB_DIAMETER_M)
    # Wentian on the starboard (-y) side, Mengtian on the port (+y) side of the hub
    node_y = _comps(model, "tianhe_node")[0].mesh.centroid[1]
    centre_y = np.mean([c.mesh.centroid[1] for c in body])
    assert np.sign(centre_y - node_y) == sign
    # wings: along x, cells facing z, near the far end of the lab, 55 m tip to tip
    wings = _comps(model, lab + r"_wing_(fwd|aft)(_mast)?")
    wext = _extent(wings)
    assert _close(wext[0], LAB_WING_SPAN_M)
    wing_y = np.mean([c.mesh.centroid[1] for c in _comps(model, lab + r"_wing_(fwd|aft)")])
    assert abs(wing_y - node_y) > 0.75 * LAB_LENGTH_M
    for side in ("fwd", "aft"):
        m = _comps(model, f"{lab}_wing_{side}")[0].mesh
        up = m.face_normals[:, 2] > 0.99
        assert _close(m.area_faces[up].sum(), LAB_WING_AREA_M2)


def test_t_shape(model):
    """Tianhe extends aft (-x) of the hub; the labs form the crossbar through the hub."""
    node = _comps(model, "tianhe_node")[0].mesh.centroid
    tianhe = _comps(model, r"tianhe_(small|large)_cylinder|tianhe_resource_section")
    assert all(c.mesh.bounds[1][0] < node[0] for c in tianhe)
    for lab in ("wentian", "mengtian"):
        for c in _comps(model, lab + r"_(work_cabin.*|payload_cabin|airlock_cabin)"):
            assert abs(c.mesh.centroid[0] - node[0]) < 0.1
            assert abs(c.mesh.centroid[2] - node[2]) < 0.1
