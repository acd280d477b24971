"""Tests for the procedural ICESat target (raytrace/targets/icesat.py).

Published values are typed here from the sources cited in the module docstring, not read
from the model:
- Wikipedia "ICESat" infobox (citing Gunter's Space Page): 2 x 2 x 3.1 m, 970 kg, 640 W.
- TBS satellite encyclopedia: launch mass 970 kg, payload (GLAS) mass 298 kg.
- NASA GCMD "GLAS": telescope diameter 1 m, instrument height ~175 cm, 300 kg.
- CSR/UT GLAS key facts: receiver telescope 1 m diameter.
- CSR/UT POD page: y along the solar-panel axis, x nominally zenith.
"""

from __future__ import annotations

import re
import time

import numpy as np
import pytest

from raytrace.model import MATERIALS, SEMANTIC_CLASSES, TargetModel
from raytrace.targets import icesat

PUB_STACK_LENGTH_M = 3.1        # Wikipedia/Gunter: 2 x 2 x 3.1 m
PUB_CROSS_SECTION_M = (1.9, 2.0)  # brief 1.9 m; Wikipedia 2.0 m
PUB_LAUNCH_MASS_KG = 970.0      # Wikipedia, TBS
PUB_GLAS_MASS_KG = 298.0        # TBS, WMO OSCAR (GCMD: 300 kg)
PUB_GLAS_HEIGHT_M = 1.75        # NASA GCMD "~175 cm"
PUB_TELESCOPE_DIAMETER_M = 1.0  # NASA GCMD, CSR/UT, Sun et al.
PUB_POWER_W = 640.0             # Wikipedia

GLAS_PARTS = ("glas_telescope_housing", "glas_optical_bench", "telescope_primary_mirror",
              "telescope_sunshade", "telescope_secondary_mirror", "telescope_spider",
              "laser_beam_expander", "glas_laser_radiator", "glas_electronics_radiator",
              "instrument_star_tracker", "laser_reference_sensor")


@pytest.fixture(scope="module")
def model() -> TargetModel:
    return icesat.build()


def _comp(model, name):
    return next(c for c in model.components if c.name == name)


def _bounds(model, names):
    meshes = [_comp(model, n).mesh for n in names]
    lo = np.min([m.bounds[0] for m in meshes], axis=0)
    hi = np.max([m.bounds[1] for m in meshes], axis=0)
    return lo, hi


def _rel(value, published):
    return abs(value - published) / published


def _mass_centre(mesh) -> np.ndarray:
    """Volume centroid (signed tetrahedra) of a closed mesh, else the area-weighted centroid."""
    tri = mesh.vertices[mesh.faces]
    if mesh.is_watertight:
        vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
        if vol.sum() > 0:
            return (vol[:, None] * tri.sum(axis=1) / 4.0).sum(axis=0) / vol.sum()
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return (area[:, None] * tri.mean(axis=1)).sum(axis=0) / area.sum()


# ---- structure ----------------------------------------------------------------------------------
def test_model_identity(model):
    assert isinstance(model, TargetModel)
    assert model.name == "icesat"
    assert 10 <= len(model.components) <= 40


def test_components_valid_and_unique(model):
    names = [c.name for c in model.components]
    assert len(set(names)) == len(names)
    for c in model.components:
        assert re.fullmatch(r"[a-z][a-z0-9_]*", c.name), c.name
        assert c.material in MATERIALS, c.name
        assert c.semantic in SEMANTIC_CLASSES, c.name
        assert c.mass_kg >= 0.0


def test_materials_fit_parts(model):
    by_name = {c.name: c for c in model.components}
    assert by_name["bus_body"].material == "gold_mli" and by_name["bus_body"].semantic == "bus"
    for tag in ("plus_y", "minus_y"):
        assert by_name[f"solar_panel_cells_{tag}"].material == "solar_cell"
        assert by_name[f"solar_panel_cells_{tag}"].semantic == "solar_panel"
        assert by_name[f"solar_array_yoke_{tag}"].material == "aluminium"
    radiators = [c for c in model.components if c.semantic == "radiator"]
    assert radiators and all(c.material in ("white_paint", "black_radiator") for c in radiators)


# ---- mesh hygiene ---------------------------------------------------------------------------------
def test_meshes_clean(model):
    for c in model.components:
        m = c.mesh
        assert len(m.faces) > 0, c.name
        assert np.all(np.isfinite(m.vertices)), c.name
        assert m.area_faces.min() > 1e-10, c.name
        key = np.sort(m.faces, axis=1)
        assert len(np.unique(key, axis=0)) == len(key), f"duplicate faces in {c.name}"
        # every part is built from closed primitives: closed, consistently wound, outward
        assert m.is_watertight, c.name
        assert m.is_winding_consistent, c.name
        assert m.volume > 0, c.name


def test_triangle_count(model):
    assert 3_000 <= model.n_triangles <= 150_000


def test_deterministic(model):
    again = icesat.build()
    assert again.component_names == model.component_names
    for a, b in zip(model.components, again.components):
        assert a.mesh.vertices.tobytes() == b.mesh.vertices.tobytes(), a.name
        assert a.mesh.faces.tobytes() == b.mesh.faces.tobytes(), a.name


def test_build_time():
    t0 = time.perf_counter()
    icesat.build()
    assert time.perf_counter() - t0 < 5.0      # brief: ~2 s; generous against slow CI


# ---- mass and centre of mass ------------------------------------------------------------------------
def test_masses_match_published(model):
    total = sum(c.mass_kg for c in model.components)
    assert total == pytest.approx(PUB_LAUNCH_MASS_KG, rel=0.005)
    glas = sum(_comp(model, n).mass_kg for n in GLAS_PARTS)
    assert glas == pytest.approx(PUB_GLAS_MASS_KG, rel=0.01)


def test_centre_of_mass_at_origin(model):
    weighted = np.zeros(3)
    total = 0.0
    for c in model.components:
        if c.mass_kg > 0:
            weighted += c.mass_kg * _mass_centre(c.mesh)
            total += c.mass_kg
    assert np.linalg.norm(weighted / total) < 1e-6


# ---- published dimensions -------------------------------------------------------------------------
def test_stack_length(model):
    """Nadir-to-zenith envelope of bus + GLAS vs the published 3.1 m."""
    lo, hi = model.bounds_m
    assert _rel(hi[0] - lo[0], PUB_STACK_LENGTH_M) < 0.10
    box_lo, box_hi = _bounds(model, ("glas_telescope_housing", "glas_optical_bench", "bus_body"))
    assert _rel(box_hi[0] - box_lo[0], PUB_STACK_LENGTH_M) < 0.10


@pytest.mark.parametrize("published", PUB_CROSS_SECTION_M)
def test_cross_section(model, published):
    lo, hi = _bounds(model, ("glas_telescope_housing", "glas_optical_bench", "bus_body"))
    assert _rel(hi[1] - lo[1], published) < 0.10
    assert _rel(hi[2] - lo[2], published) < 0.10
    # without the wings the whole model stays within the published cross-section (+10 %)
    lo_all, hi_all = model.bounds_m
    assert _rel(hi_all[2] - lo_all[2], published) < 0.10


def test_glas_height(model):
    lo, hi = _bounds(model, ("glas_telescope_housing", "glas_optical_bench"))
    assert _rel(hi[0] - lo[0], PUB_GLAS_HEIGHT_M) < 0.10


def test_telescope_aperture_and_boresight(model):
    mirror = _comp(model, "telescope_primary_mirror").mesh
    ext = mirror.extents
    assert _rel(ext[1], PUB_TELESCOPE_DIAMETER_M) < 0.10
    assert _rel(ext[2], PUB_TELESCOPE_DIAMETER_M) < 0.10
    shade = _comp(model, "telescope_sunshade").mesh
    assert shade.extents[1] >= PUB_TELESCOPE_DIAMETER_M
    # the telescope looks nadir (-x): it sits at the low-x end, the mirror is concave towards -x
    lo, _ = model.bounds_m
    assert shade.bounds[0][0] == pytest.approx(lo[0], abs=0.05)
    assert mirror.bounds[1][0] < _comp(model, "bus_body").mesh.bounds[0][0]
    v = mirror.vertices
    front = v[v[:, 0] < mirror.bounds[0][0] + 0.06]            # the concave front surface
    r = np.hypot(front[:, 1] - mirror.centroid[1], front[:, 2] - mirror.centroid[2])
    assert front[np.argmin(r), 0] > front[np.argmax(r), 0]      # centre deeper than rim


def test_axis_convention(model):
    """+x zenith (GPS antennas on top), +y along the solar-array axis (CSR/UT)."""
    _, hi = model.bounds_m
    for n in ("gps_antenna_1", "gps_antenna_2"):
        assert _comp(model, n).mesh.bounds[1][0] > hi[0] - 0.25
    for tag, sign in (("plus_y", 1), ("minus_y", -1)):
        cells = _comp(model, f"solar_panel_cells_{tag}").mesh
        assert sign * cells.centroid[1] > 2.0
        # cells face +z: the cell layer sits on the +z side of its substrate
        sub = _comp(model, f"solar_panel_substrate_{tag}").mesh
        assert cells.bounds[1][2] > sub.bounds[1][2] and cells.centroid[2] > sub.centroid[2]


def test_solar_wings_plausible(model):
    """Wing size is not published; check it against the 640 W power figure and the brief."""
    bus_lo, bus_hi = _bounds(model, ("bus_body",))
    for tag in ("plus_y", "minus_y"):
        sub = _comp(model, f"solar_panel_substrate_{tag}").mesh
        cells = _comp(model, f"solar_panel_cells_{tag}").mesh
        thickness = cells.bounds[1][2] - sub.bounds[0][2]
        assert 0.02 <= thickness <= 0.05
        # the wing root is off the bus side, attached through drive + yoke (no float, no overlap)
        drive = _comp(model, f"solar_array_drive_{tag}").mesh
        assert min(abs(drive.bounds[0][1]), abs(drive.bounds[1][1])) == pytest.approx(
            bus_hi[1], abs=0.01)
    cell_area = sum(np.prod(_comp(model, f"solar_panel_substrate_{t}").mesh.extents[:2])
                    for t in ("plus_y", "minus_y"))
    # 640 W orbit average at ~200 W/m^2 peak x ~0.45 orbit/cosine factor -> ~7 m^2
    assert PUB_POWER_W / 200.0 / 0.6 < cell_area < PUB_POWER_W / 200.0 / 0.3
    span = model.bounds_m[1][1] - model.bounds_m[0][1]
    assert 3.0 * PUB_CROSS_SECTION_M[0] < span < 9.0


def test_bounding_radius(model):
    lo, hi = model.bounds_m
    r = model.bounding_radius_m
    assert 0.5 * np.max(hi - lo) <= r + 1e-9
    assert 3.5 < r < 4.5
