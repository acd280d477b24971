"""Cassini–Huygens target: published dimensions, mesh hygiene, centre of mass, determinism.

Published figures are typed here from the sources cited in ``raytrace/targets/cassini.py``
(not read from the module), so a wrong constant there fails here.
"""

import math
import re

import numpy as np
import pytest

from raytrace.model import MATERIALS, SEMANTIC_CLASSES
from raytrace.targets.cassini import build

# --- published values -------------------------------------------------------------------
HEIGHT_M = 6.8                 # "6.8 meters (22.3 feet) high" (engineering.com; C. Winter); JPL ">6.7 m"
WIDTH_M = 4.0                  # ">4 meters wide (not including a deployed boom and antennas)" (JPL)
HGA_DIAMETER_M = 4.0           # "fixed, four-meter diameter high-gain antenna" (ESA)
MAG_BOOM_M = 11.0              # "11-meter magnetometer boom" (NASA SP-533; JPL MAG page)
RPWS_M = 10.0                  # "triad of 10-meter conducting monopoles" (NAIF cas_v37.tf)
RPWS_V_DEG = 120.0             # EX+/EX- "120-degree V" about +Y (NAIF cas_v37.tf)
RPWS_TILT_DEG = 37.0           # tilt of the V, and EZ angle from +Z (NAIF cas_v37.tf)
RTG_LENGTH_M = 1.14            # GPHS-RTG (Bennett, AIAA 2006-4191)
RTG_DIAMETER_M = 0.422
RTG_MASS_KG = 57.0
HUYGENS_DIAMETER_M = 2.7       # "The Huygens probe measured 2.7 metres across" (ESA)
HUYGENS_MASS_KG = 318.0 + 30.0  # probe + probe support equipment (ESA)
ORBITER_DRY_KG = 2150.0        # (engineering.com; C. Winter)
PROPELLANT_KG = 3132.0
LAUNCH_MASS_KG = 5600.0        # "about 5,600 kilograms at launch" (engineering.com)

REL = 0.10


@pytest.fixture(scope="module")
def model():
    return build()


def comp(model, name):
    return next(c for c in model.components if c.name == name)


def extents_of(components):
    lo = np.min([c.mesh.bounds[0] for c in components], axis=0)
    hi = np.max([c.mesh.bounds[1] for c in components], axis=0)
    return hi - lo


def principal_axis(vertices):
    v = np.asarray(vertices, float)
    centred = v - v.mean(axis=0)
    return np.linalg.svd(centred, full_matrices=False)[2][0]


def close(value, published, rel=REL):
    return abs(value - published) <= rel * published


def is_antenna_or_boom(name):
    return name.startswith("rpws_antenna_") or name in ("magnetometer_boom", "magnetometer_fluxgate",
                                                         "magnetometer_vshm")


# --- identity, materials, names ---------------------------------------------------------
def test_components_valid_and_unique(model):
    names = [c.name for c in model.components]
    assert model.name == "cassini"
    assert len(names) == len(set(names))
    assert 10 <= len(names) <= 60
    for c in model.components:
        assert re.fullmatch(r"[a-z][a-z0-9_]*", c.name), c.name
        assert c.material in MATERIALS
        assert c.semantic in SEMANTIC_CLASSES
        assert math.isfinite(c.mass_kg) and c.mass_kg >= 0.0


def test_key_parts_present_with_fitting_materials(model):
    assert comp(model, "high_gain_antenna").material == "dish"
    assert comp(model, "high_gain_antenna").semantic == "dish"
    assert comp(model, "propulsion_module").material == "gold_mli"
    assert comp(model, "huygens_back_cover").semantic == "probe"
    rtgs = [c for c in model.components if c.semantic == "rtg"]
    assert len(rtgs) == 3 and all(c.material in ("black_paint", "titanium") for c in rtgs)
    engines = [c for c in model.components if c.semantic == "engine"]
    assert len(engines) == 2
    assert len([c for c in model.components if c.name.startswith("rpws_antenna_")]) == 3


# --- published dimensions ---------------------------------------------------------------
def test_overall_height_and_width(model):
    body = [c for c in model.components if not is_antenna_or_boom(c.name)]
    ext = extents_of(body)
    assert close(ext[2], HEIGHT_M), ext
    assert close(max(ext[0], ext[1]), WIDTH_M), ext


def test_high_gain_antenna_diameter_and_position(model):
    dish = comp(model, "high_gain_antenna").mesh
    assert close(dish.extents[0], HGA_DIAMETER_M) and close(dish.extents[1], HGA_DIAMETER_M)
    # on top: -Z is the HGA boresight, nothing but the feed/subreflector/LGA1/antennas above it
    assert dish.bounds[0][2] < comp(model, "upper_equipment_module").mesh.bounds[0][2]


def test_magnetometer_boom_length_along_plus_y(model):
    boom = comp(model, "magnetometer_boom").mesh
    assert close(boom.extents[1], MAG_BOOM_M)
    assert boom.extents[0] < 0.5 and boom.extents[2] < 0.5
    assert boom.bounds[0][1] > 0.0                      # entirely on the +Y side
    tip = comp(model, "magnetometer_vshm").mesh.centroid
    assert tip[1] > MAG_BOOM_M * (1.0 - REL)


def test_rpws_antennas(model):
    dirs = {}
    for name in ("rpws_antenna_x_plus", "rpws_antenna_x_minus", "rpws_antenna_z_plus"):
        v = comp(model, name).mesh.vertices
        a = principal_axis(v)
        proj = (v - v.mean(axis=0)) @ a
        assert close(proj.max() - proj.min(), RPWS_M)
        if a[1] < 0:                                      # all three point towards +Y
            a = -a
        dirs[name] = a
    v_angle = math.degrees(math.acos(np.clip(dirs["rpws_antenna_x_plus"] @ dirs["rpws_antenna_x_minus"], -1, 1)))
    assert abs(v_angle - RPWS_V_DEG) < 5.0
    ez_angle = math.degrees(math.acos(np.clip(dirs["rpws_antenna_z_plus"] @ [0.0, 0.0, 1.0], -1, 1)))
    assert abs(ez_angle - RPWS_TILT_DEG) < 3.0
    # the V is tilted up, towards the HGA (-Z)
    assert dirs["rpws_antenna_x_plus"][2] < 0 and dirs["rpws_antenna_x_minus"][2] < 0


def test_rtg_size_and_mass(model):
    rtgs = [c for c in model.components if c.semantic == "rtg"]
    for c in rtgs:
        v = c.mesh.vertices
        a = principal_axis(v)
        centred = v - v.mean(axis=0)
        along = centred @ a
        radial = np.linalg.norm(centred - np.outer(along, a), axis=1)
        assert close(along.max() - along.min(), RTG_LENGTH_M)
        assert close(2.0 * radial.max(), RTG_DIAMETER_M)
        assert close(c.mass_kg, RTG_MASS_KG)
        assert c.mesh.centroid[2] > 0.5                   # at the lower (engine) end of the stack


def test_huygens_probe(model):
    front = comp(model, "huygens_front_shield").mesh
    assert close(front.extents[1], HUYGENS_DIAMETER_M) and close(front.extents[2], HUYGENS_DIAMETER_M)
    assert front.extents[0] < 0.5 * HUYGENS_DIAMETER_M       # shallow cone
    assert front.bounds[1][0] < -0.9                         # mounted on the -X side
    probe_mass = sum(c.mass_kg for c in model.components if c.name.startswith("huygens_"))
    assert close(probe_mass, HUYGENS_MASS_KG, rel=0.01)


def test_masses(model):
    total = sum(c.mass_kg for c in model.components)
    assert close(total, LAUNCH_MASS_KG)
    probe = sum(c.mass_kg for c in model.components if c.name.startswith("huygens_"))
    assert close(total - probe - PROPELLANT_KG, ORBITER_DRY_KG, rel=0.02)
    assert comp(model, "propulsion_module").mass_kg > PROPELLANT_KG


def test_layout_follows_cassini_frame(model):
    z = {c.name: c.mesh.centroid[2] for c in model.components}
    assert z["high_gain_antenna"] < z["electronics_bus"] < z["propulsion_module"] < z["main_engine_prime"]
    assert comp(model, "remote_sensing_pallet").mesh.centroid[0] > 0.5        # +X side
    assert comp(model, "fields_particles_pallet").mesh.centroid[0] < -0.5     # -X side


# --- centre of mass ---------------------------------------------------------------------
def _centre(mesh):
    v = np.asarray(mesh.vertices, float)
    tri = v[np.asarray(mesh.faces)]
    if mesh.is_watertight:
        vol6 = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2]))   # 6 x signed tetra volume
        if vol6.sum() > 0:
            return (vol6[:, None] * tri.sum(axis=1) / 4.0).sum(axis=0) / vol6.sum()
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return (area[:, None] * tri.mean(axis=1)).sum(axis=0) / area.sum()


def test_centre_of_mass_at_origin(model):
    m = np.array([c.mass_kg for c in model.components])
    centres = np.array([_centre(c.mesh) for c in model.components])
    com = (m[:, None] * centres).sum(axis=0) / m.sum()
    assert np.linalg.norm(com) < 1e-6


# --- mesh hygiene -----------------------------------------------------------------------
def test_mesh_hygiene(model):
    for c in model.components:
        v = np.asarray(c.mesh.vertices)
        f = np.asarray(c.mesh.faces)
        assert len(f) > 0 and np.all(np.isfinite(v)), c.name
        tri = v[f]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        assert area.min() > 1e-10, c.name
        assert len(np.unique(np.sort(f, axis=1), axis=0)) == len(f), c.name
        assert c.mesh.is_watertight, c.name
        assert c.mesh.is_winding_consistent and c.mesh.volume > 0.0, c.name


def test_triangle_count(model):
    assert 3_000 <= model.n_triangles <= 150_000


def test_bounding_radius(model):
    r = model.bounding_radius_m
    assert MAG_BOOM_M < r < MAG_BOOM_M + HEIGHT_M


def test_deterministic(model):
    again = build()
    assert again.component_names == model.component_names
    for a, b in zip(model.components, again.components):
        assert np.asarray(a.mesh.vertices).tobytes() == np.asarray(b.mesh.vertices).tobytes()
        assert np.asarray(a.mesh.faces).tobytes() == np.asarray(b.mesh.faces).tobytes()
        assert a.mass_kg == b.mass_kg and a.material == b.material
