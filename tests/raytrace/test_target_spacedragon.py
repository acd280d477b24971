"""Crew Dragon target: published dimensions, parts, mass properties and mesh hygiene.

Published figures (typed from the sources cited in ``raytrace/targets/spacedragon.py``):
SpaceX Dragon page — height 8.1 m with trunk, diameter 4 m, half of the trunk covered in solar
cells, 16 Dracos, 8 SuperDracos; Wikipedia "SpaceX Dragon 2" — capsule 4.5 m tall, sidewall
angle 15 deg, dry mass 7,700 kg, propellant 2,562 kg, launch mass 12,500 kg; SpaceX CRS-6
press kit — Dragon 4.4 m tall, trunk 3.66 m wide.
"""

import math
import time

import numpy as np
import pytest

from raytrace.model import MATERIALS, SEMANTIC_CLASSES
from raytrace.targets.spacedragon import build

HEIGHT_WITH_TRUNK_M = 8.1        # SpaceX
CAPSULE_DIAMETER_M = 4.0         # SpaceX
CAPSULE_HEIGHT_M = 4.45          # 4.4 m (CRS-6 press kit) .. 4.5 m (Wikipedia)
TRUNK_DIAMETER_M = 3.66          # CRS-6 press kit
TRUNK_HEIGHT_M = HEIGHT_WITH_TRUNK_M - 4.4   # below the capsule
SIDEWALL_ANGLE_DEG = 15.0        # Wikipedia
CAPSULE_WET_KG = 7700.0 + 2562.0  # Wikipedia: dry + propellant
LAUNCH_MASS_KG = 12500.0         # Wikipedia
REL = 0.10


@pytest.fixture(scope="module")
def model():
    return build()


@pytest.fixture(scope="module")
def parts(model):
    return {c.name: c for c in model.components}


@pytest.fixture(scope="module")
def axis_yz(parts):
    """(y, z) of the symmetry axis: centre of the trunk tube's bounds."""
    lo, hi = parts["trunk"].mesh.bounds
    return 0.5 * (lo[1:] + hi[1:])


def radial(vertices, axis_yz):
    return np.linalg.norm(vertices[:, 1:] - axis_yz, axis=1)


def azimuth_deg(point, axis_yz):
    """Azimuth about +x measured from +z towards -y [deg]."""
    dy, dz = point[1] - axis_yz[0], point[2] - axis_yz[1]
    return math.degrees(math.atan2(-dy, dz)) % 360.0


def test_components_valid_and_unique(model):
    names = model.component_names
    assert len(names) == len(set(names))
    assert 10 <= len(names) <= 40
    for c in model.components:
        assert c.name == c.name.lower() and " " not in c.name
        assert c.material in MATERIALS
        assert c.semantic in SEMANTIC_CLASSES
        assert c.mass_kg >= 0.0


def test_required_materials(parts):
    expected = {"capsule": "white_paint", "heat_shield": "heat_shield", "trunk": "white_paint",
                "nose_cone": "white_paint", "docking_adapter": "aluminium"}
    for name, material in expected.items():
        assert parts[name].material == material
    assert parts["heat_shield"].semantic == "heat_shield"
    assert parts["docking_adapter"].semantic == "docking_port"
    fins = [c for n, c in parts.items() if n.startswith("trunk_fin_")]
    assert len(fins) == 4 and all(c.material == "white_paint" for c in fins)
    solar = [c for c in parts.values() if c.semantic == "solar_panel"]
    assert solar and all(c.material == "solar_cell" for c in solar)


def test_overall_height_and_diameter(model, parts, axis_yz):
    trunk_bottom = parts["trunk"].mesh.bounds[0, 0]
    capsule_top = parts["capsule"].mesh.bounds[1, 0]
    nose_height = float(np.min(parts["nose_cone"].mesh.bounding_box_oriented.primitive.extents))
    closed_height = capsule_top - trunk_bottom + nose_height
    assert closed_height == pytest.approx(HEIGHT_WITH_TRUNK_M, rel=REL)
    # with the nose cone swung open the vehicle is longer, but by less than the cone's width
    length = model.bounds_m[1, 0] - model.bounds_m[0, 0]
    assert HEIGHT_WITH_TRUNK_M * (1 - REL) < length < HEIGHT_WITH_TRUNK_M + 2.5
    # the largest diameter of the capsule (fins and the open nose cone excluded)
    body = np.concatenate([parts[n].mesh.vertices for n in ("capsule", "heat_shield")])
    assert 2 * radial(body, axis_yz).max() == pytest.approx(CAPSULE_DIAMETER_M, rel=REL)


def test_capsule_height(parts):
    apex = parts["heat_shield"].mesh.bounds[0, 0]
    capsule_top = parts["capsule"].mesh.bounds[1, 0]
    nose_height = float(np.min(parts["nose_cone"].mesh.bounding_box_oriented.primitive.extents))
    assert capsule_top - apex + nose_height == pytest.approx(CAPSULE_HEIGHT_M, rel=REL)
    assert parts["heat_shield"].mesh.bounds[0, 0] < parts["capsule"].mesh.bounds[0, 0]


def test_trunk_dimensions(parts, axis_yz):
    trunk = parts["trunk"].mesh
    assert 2 * radial(trunk.vertices, axis_yz).max() == pytest.approx(TRUNK_DIAMETER_M, rel=REL)
    below_capsule = parts["heat_shield"].mesh.bounds[0, 0] - trunk.bounds[0, 0]
    assert below_capsule == pytest.approx(TRUNK_HEIGHT_M, rel=REL)
    # the trunk's top reaches the capsule (it carries it): no gap above 1 cm
    assert trunk.bounds[1, 0] >= parts["heat_shield"].mesh.bounds[0, 0] - 0.01


def test_sidewall_angle(parts, axis_yz):
    v = parts["capsule"].mesh.vertices
    r = radial(v, axis_yz)
    wall = (r > 1.3) & (r < 1.95)
    slope, _ = np.polyfit(v[wall, 0], r[wall], 1)
    assert math.degrees(math.atan(-slope)) == pytest.approx(SIDEWALL_ANGLE_DEG, abs=1.5)


def test_superdraco_pods_and_dracos(parts, axis_yz):
    nozzles = [parts[f"superdraco_nozzles_{k}"] for k in range(1, 5)]
    assert all(c.mesh.body_count == 2 for c in nozzles)            # 4 pods x 2 = 8 engines
    assert all(c.semantic == "engine" for c in nozzles)
    az = sorted(azimuth_deg(parts[f"superdraco_pod_{k}"].mesh.centroid, axis_yz)
                for k in range(1, 5))
    np.testing.assert_allclose(np.diff(az), 90.0, atol=2.0)        # evenly spaced
    # pods sit on the lower sidewall of the capsule
    cap_lo, cap_hi = parts["capsule"].mesh.bounds[:, 0]
    for k in range(1, 5):
        x = parts[f"superdraco_pod_{k}"].mesh.centroid[0]
        assert cap_lo < x < 0.5 * (cap_lo + cap_hi)
    draco = parts["draco_side_nozzles"].mesh.body_count + parts["draco_forward"].mesh.body_count
    assert draco == 16


def test_trunk_solar_and_radiator_halves(parts, axis_yz):
    def span_deg(names):
        total = 0.0
        for n in names:
            v = parts[n].mesh.vertices
            a = np.unwrap(np.radians([azimuth_deg(p, axis_yz) for p in v]))
            total += math.degrees(a.max() - a.min())
        return total

    solar = [n for n in parts if n.startswith("trunk_solar_cells")]
    rads = [n for n in parts if n.startswith("trunk_radiator")]
    assert span_deg(solar) == pytest.approx(180.0, rel=REL)
    assert span_deg(rads) == pytest.approx(180.0, rel=REL)
    # cells on the non-hatch side: opposite the hatch about the axis
    solar_c = np.mean([parts[n].mesh.centroid for n in solar], axis=0)
    hatch_c = parts["side_hatch"].mesh.centroid
    assert np.dot(solar_c[1:] - axis_yz, hatch_c[1:] - axis_yz) < 0
    # thin panels, 1-5 cm proud of the trunk
    for n in solar + rads:
        r = radial(parts[n].mesh.vertices, axis_yz)
        assert 0.01 <= r.max() - TRUNK_DIAMETER_M / 2 <= 0.05


def test_fins_at_aft_end(parts, axis_yz):
    trunk_lo, trunk_hi = parts["trunk"].mesh.bounds[:, 0]
    az = sorted(azimuth_deg(parts[f"trunk_fin_{k}"].mesh.centroid, axis_yz) for k in range(1, 5))
    np.testing.assert_allclose(np.diff(az), 90.0, atol=2.0)
    for k in range(1, 5):
        fin = parts[f"trunk_fin_{k}"].mesh
        assert fin.bounds[0, 0] == pytest.approx(trunk_lo, abs=0.02)
        assert fin.bounds[1, 0] < 0.5 * (trunk_lo + trunk_hi)        # aft half only
        assert radial(fin.vertices, axis_yz).min() <= TRUNK_DIAMETER_M / 2 + 0.01   # attached


def test_nose_cone_open_and_docking_adapter_exposed(parts, axis_yz):
    nose = parts["nose_cone"].mesh
    assert radial(nose.centroid[None], axis_yz)[0] > 1.0              # swung off the axis
    dock = parts["docking_adapter"].mesh
    assert radial(dock.vertices, axis_yz).max() < 1.0
    assert dock.bounds[1, 0] > parts["capsule"].mesh.bounds[1, 0]      # stands proud
    # nothing covers the docking axis in front of the adapter
    on_axis = [c for c in parts.values() if c.name != "docking_adapter"
               and np.any((radial(c.mesh.vertices, axis_yz) < 0.3)
                          & (c.mesh.vertices[:, 0] > dock.bounds[1, 0] + 0.05))]
    assert not on_axis


def test_masses(parts):
    total = sum(c.mass_kg for c in parts.values())
    assert total == pytest.approx(LAUNCH_MASS_KG, rel=REL)
    trunk = sum(c.mass_kg for n, c in parts.items() if n.startswith("trunk"))
    assert 1500.0 <= trunk <= 2300.0
    assert total - trunk == pytest.approx(CAPSULE_WET_KG, rel=REL)


def test_centre_of_mass_at_origin(model):
    com, total = np.zeros(3), 0.0
    for c in model.components:
        if c.mass_kg <= 0:
            continue
        m = c.mesh
        if m.is_watertight and m.volume > 0:
            # volume centroid from signed tetrahedra about the origin
            tri = m.triangles
            vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
            centre = (vol[:, None] * tri.sum(axis=1) / 4.0).sum(axis=0) / vol.sum()
        else:
            centre = (m.area_faces[:, None] * m.triangles_center).sum(axis=0) / m.area
        com += c.mass_kg * centre
        total += c.mass_kg
    assert np.linalg.norm(com / total) < 1e-6


def test_mesh_hygiene(model):
    for c in model.components:
        m = c.mesh
        assert len(m.faces) > 0
        assert np.all(np.isfinite(m.vertices))
        assert m.area_faces.min() > 1e-10, c.name
        key = np.sort(m.faces, axis=1)
        assert len(np.unique(key, axis=0)) == len(key), c.name
        assert m.is_watertight and m.is_winding_consistent and m.volume > 0, c.name


def test_triangle_count_and_bounding_radius(model):
    assert 3000 <= model.n_triangles <= 150000
    assert HEIGHT_WITH_TRUNK_M / 2 < model.bounding_radius_m < 7.0


def test_deterministic_and_fast():
    t0 = time.perf_counter()
    a = build()
    elapsed = time.perf_counter() - t0
    b = build()
    assert a.component_names == b.component_names
    for ca, cb in zip(a.components, b.components):
        assert ca.mesh.vertices.tobytes() == cb.mesh.vertices.tobytes()
        assert ca.mesh.faces.tobytes() == cb.mesh.faces.tobytes()
    assert elapsed < 2.0


def test_registry_loads_spacedragon():
    from raytrace.targets import load_target
    assert load_target("spacedragon").name == "spacedragon"
