"""ICESat (Ice, Cloud and land Elevation Satellite, NASA/Ball Aerospace, 2003-2010), built procedurally.

ICESat was a Ball Commercial Platform 2000 (BCP 2000) bus carrying one instrument, the Geoscience
Laser Altimeter System (GLAS): a 1 m receiver telescope, three Nd:YAG lasers and a stellar reference
system. The stack is a box about 3.1 m tall (nadir-zenith) and 1.9-2.0 m square. GLAS forms the
nadir end with the telescope aperture in the Earth-facing deck; the bus with its avionics and
hydrazine tanks forms the zenith end. Two single-axis solar array wings leave the bus sides.
The model shows them in the "sailboat" attitude: the panels lie in the x-y plane and the cells face
+z.

Body frame (ICESat spacecraft axes, CSR POD page [5])
-----------------------------------------------------
- **+x**: zenith. The GLAS telescope, the laser and the retroreflector look along **-x** (nadir).
- **+y**: along the solar-array axis (the wings reach out along +-y).
- **+z**: completes the right-handed frame. The solar cells face +z. The ledge with the two GLAS
  star cameras (IST, LRS) is on the +z side.
- Origin: centre of mass (:func:`~raytrace.model.centre_on_mass`), metres.

Dimensions and sources
----------------------
=============================  ==========================  ===============================
Part                           Value used                  Source
=============================  ==========================  ===============================
Stack envelope, x              3.22 m (boxes 2.90 m)       [1] 3.1 m (2 x 2 x 3.1 m)
GLAS box / bus box, x          1.75 m / 1.15 m             [3] / remainder of [1]
Bus cross-section, y x z       1.90 x 1.90 m               [1] 2.0 m; brief 1.9 m
Launch mass                    970 kg                      [1], [2]
GLAS mass                      298 kg                      [2], [3] (300 kg)
GLAS instrument height         1.75 m                      [3] "~175 cm"
Receiver telescope aperture    1.00 m (beryllium)          [3], [4], [6]
Power (EOL)                    640 W                       [1] (730 W DC in [2])
Solar wings, each              2.40 x 1.50 m, 3.6 m^2      estimate, see Notes
Wing tip to tip                ~7.6 m                      estimate, see Notes
Separation ring                0.98 m outer diameter       Delta II 37-in (0.94 m) clamp band
=============================  ==========================  ===============================

Notes
-----
No source found here gives the size of the solar wings. They are sized from the power figure [1]:
a GaAs array at about 200 W/m^2 (normal sun, beginning of life), with about 60 % sunlit fraction
and cosine losses over a low-Earth orbit, needs about 7 m^2 for 640 W orbit average at end of life.
Each wing is therefore one rigid 2.4 x 1.5 m panel. It is short enough to fold against a 3.1 m
bus side at launch. The stacking (GLAS box at the nadir end under the bus, telescope in the
nadir deck with a 0.12 m sunshade lip) follows the published 3.1 m height, the 1.75 m GLAS height
and the nadir-looking telescope; no drawing was found to confirm it. The parts of the GLAS box (telescope housing, optical bench, laser and
electronics radiators with OSRs), the +z ledge for the GLAS star cameras, and the zenith-deck
layout (GPS choke rings, bus star trackers, S-band omni, separation ring) are schematic. Their
places are chosen to match the published function of each part: nadir-looking telescope and
laser, zenith-looking star cameras and GPS antennas, Earth-facing retroreflector and X-band
antenna. Masses split the 970 kg launch mass: GLAS parts sum to 298 kg, and the bus (with
hydrazine and wings) takes the other 672 kg.

References
----------
[1] Wikipedia, "ICESat" infobox: BCP-2000, Ball Aerospace, launch mass 970 kg, dimensions
    2 x 2 x 3.1 m, power 640 W (citing Gunter's Space Page, "ICESat (EOS-LAM)").
[2] TBS satellite encyclopedia, "ICESat": launch mass 970 kg, payload mass 298 kg, DC power
    730 W, BCP-2000. http://www.tbs-satellite.com/tse/online/sat_icesat.html
[3] NASA GCMD instrument keyword "GLAS" (text from the NASA GLAS page): "Telescope diameter is
    1 m, instrument height is ~175 cm", mass 300 kg. WMO OSCAR "GLAS": mass 298 kg.
[4] CSR/UT Austin, GLAS Key Facts: "Receiver telescope is 1 meter diameter".
    http://www.csr.utexas.edu/glas/facts.html
[5] CSR/UT Austin, ICESat POD information: spacecraft axes "y: along solar panel axis, x: ...
    nominally in the zenith direction". http://www.csr.utexas.edu/glas/podinfo/
[6] Sun et al., "Performance of the GLAS space lidar receiver through its seven-year space
    mission" (NTRS 20110008282): "a 1-m diameter telescope". eoPortal "ICESat": BCP 2000,
    panel-post aluminium honeycomb structure, three-axis stabilised.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from ..model import Component, TargetModel, centre_on_mass

__all__ = ["GLAS_MASS_KG", "LAUNCH_MASS_KG", "build"]

# ---- published figures (see the table in the module docstring) -------------------------------
LAUNCH_MASS_KG = 970.0          # [1], [2]
GLAS_MASS_KG = 298.0            # [2], [3]
STACK_LENGTH_M = 3.10           # bus + GLAS, nadir to zenith [1]
BUS_SIDE_M = 1.90               # square cross-section [1] / brief
GLAS_HEIGHT_M = 1.75            # [3]
TELESCOPE_DIAMETER_M = 1.00     # [3], [4], [6]

# ---- layout in the build frame (x = 0 at the GLAS nadir deck; moved to the CoM at the end) ---
_H = BUS_SIDE_M / 2.0                       # half side of the square cross-section [m]
_X_GLAS_TOP = GLAS_HEIGHT_M                 # GLAS / bus interface plane [m]
_X_DECK = STACK_LENGTH_M - 0.20             # zenith deck; deck equipment sticks out ~0.15 m
_X_BENCH = 0.90                             # telescope housing / optical bench split [m]
_LEDGE_Z = 0.55                             # bus spans z in [-_H, _LEDGE_Z]; ledge beyond it
_BUS_ZC = 0.5 * (-_H + _LEDGE_Z)            # bus centre in z [m]
_TEL_R = TELESCOPE_DIAMETER_M / 2.0         # primary-mirror radius [m]
_SHADE_R_IN, _SHADE_R_OUT = 0.525, 0.550    # telescope sunshade tube radii [m]
_HOLE_R = 0.565                             # aperture hole in the nadir deck [m]
_SHADE_X0 = -0.12                           # sunshade lip below the nadir deck [m]
_E = 0.004                                  # attached parts sink this far into their mount [m]
# the optical bench is this much narrower than the housing and the bus it sinks into: with the
# same cross-section, their side faces overlapped in the same plane along both 4 mm joints, and
# which part a ray hit there (its id in the mask, and in Cycles its shadow: black lines) was a
# tie decided by float rounding
_INSET = 0.001

_WING_SPAN_M = 2.40                         # panel length along y (estimate, see Notes)
_WING_HEIGHT_M = 1.50                       # panel width along x (estimate)
_WING_T = 0.025                             # substrate thickness [m]
_CELL_T = 0.008                             # cell layer thickness [m]
_DRIVE_LEN = 0.12                           # array drive length along y [m]
_YOKE_LEN = 0.35                            # yoke reach along y [m]
_WING_XC = 2.30                             # array axis height (x) [m]
_WING_ZC = _BUS_ZC                          # array axis z [m]


# ---- small geometry helpers -------------------------------------------------------------------
def _box(lo, hi) -> trimesh.Trimesh:
    """Axis-aligned box between corners ``lo`` and ``hi`` [m]."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(extents=hi - lo,
                                transform=trimesh.transformations.translation_matrix((lo + hi) / 2))


def _align(axis, origin) -> np.ndarray:
    """4x4 transform taking +z to ``axis`` and the origin to ``origin``."""
    axis = np.asarray(axis, float)
    m = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], axis / np.linalg.norm(axis))
    m[:3, 3] = origin
    return m


def _rod(p0, p1, radius, sections=16) -> trimesh.Trimesh:
    """Solid cylinder from point ``p0`` to point ``p1`` [m]."""
    return trimesh.creation.cylinder(radius=radius, sections=sections, segment=[p0, p1])


def _tube(p0, p1, r_in, r_out, sections=64) -> trimesh.Trimesh:
    """Hollow cylinder (closed annular solid) from ``p0`` to ``p1`` [m]."""
    return trimesh.creation.annulus(r_min=r_in, r_max=r_out, sections=sections, segment=[p0, p1])


def _cone(base_centre, axis, radius, height, sections=24) -> trimesh.Trimesh:
    """Cone with its base at ``base_centre`` and its tip ``height`` along ``axis`` [m]."""
    return trimesh.creation.cone(radius=radius, height=height, sections=sections,
                                 transform=_align(axis, base_centre))


def _merge(meshes) -> trimesh.Trimesh:
    return trimesh.util.concatenate(list(meshes))


def _square_plate_with_hole(half_side, hole_r, x0, x1, sections=96) -> trimesh.Trimesh:
    """Square prism along x (side ``2*half_side``) with a centred round hole, watertight.

    Built directly: ``sections`` (a multiple of 8) rays from the y-z centre, each with one vertex
    on the hole circle and one on the square; the rays at 45 degrees hit the square corners
    exactly, so the outer walls stay flat.
    """
    if sections % 8:
        raise ValueError(f"sections must be a multiple of 8, got {sections}")
    theta = np.pi / 4 + 2 * np.pi * np.arange(sections) / sections
    c, s = np.cos(theta), np.sin(theta)
    scale = half_side / np.maximum(np.abs(c), np.abs(s))
    inner = np.column_stack((hole_r * c, hole_r * s))
    outer = np.column_stack((scale * c, scale * s))
    n = sections
    verts = np.vstack([np.column_stack((np.full(n, x), ring[:, 0], ring[:, 1]))
                       for x in (x0, x1) for ring in (inner, outer)])
    ib, ob, it, ot = 0, n, 2 * n, 3 * n          # offsets: inner/outer x bottom/top
    k = np.arange(n)
    k1 = (k + 1) % n
    quads = np.vstack([
        np.column_stack((it + k, ot + k, ot + k1, it + k1)),    # top (x1) face
        np.column_stack((ib + k, ib + k1, ob + k1, ob + k)),    # bottom (x0) face
        np.column_stack((ob + k, ob + k1, ot + k1, ot + k)),    # outer walls
        np.column_stack((ib + k, it + k, it + k1, ib + k1)),    # hole wall
    ])
    faces = np.vstack((quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]))
    mesh = trimesh.Trimesh(vertices=verts, faces=faces, process=True)
    mesh.fix_normals()
    return mesh


def _primary_mirror(x_rim, sag, thickness, radius, sections=96) -> trimesh.Trimesh:
    """Concave mirror facing -x: front surface sag ``sag`` deep, flat back ``thickness`` behind."""
    r = np.linspace(0.0, radius, 9)
    front = x_rim + sag * (1.0 - (r / radius) ** 2)          # centre deepest (largest x)
    x_back = x_rim + sag + thickness
    # (radius, height) profile from the axis at the front, out to the rim, back to the axis
    profile = np.vstack((np.column_stack((r, front)), [[radius, x_back], [0.0, x_back]]))
    mesh = trimesh.creation.revolve(profile, sections=sections)     # axis = z
    if mesh.volume < 0:
        mesh.invert()
    # revolve builds the mirror about z with heights along z; rotate z -> x (heights become x)
    mesh.apply_transform(_align([1.0, 0.0, 0.0], [0.0, 0.0, 0.0]))
    return mesh


def _star_camera(base_centre, boresight, body=(0.20, 0.20, 0.24), shade_len=0.20,
                 shade_r=(0.075, 0.09)) -> trimesh.Trimesh:
    """Star camera: a box body on a deck plus a sunshade tube along ``boresight``."""
    boresight = np.asarray(boresight, float)
    boresight /= np.linalg.norm(boresight)
    box = trimesh.creation.box(extents=(body[0], body[1], body[2]))
    box.apply_transform(_align(boresight, base_centre + boresight * (body[2] / 2 - _E)))
    p0 = base_centre + boresight * (body[2] - 0.01)
    shade = _tube(p0, p0 + boresight * shade_len, shade_r[0], shade_r[1], sections=32)
    return _merge((box, shade))


def _solar_wing(side: int):
    """Drive, yoke, substrate and cell layer of the wing on the ``side`` (+1 or -1) of y."""
    y_face = side * _H
    y_drive = y_face + side * _DRIVE_LEN
    y_in = y_drive + side * _YOKE_LEN                       # panel inner edge
    y_out = y_in + side * _WING_SPAN_M
    x_lo, x_hi = _WING_XC - _WING_HEIGHT_M / 2, _WING_XC + _WING_HEIGHT_M / 2

    drive = _rod((_WING_XC, y_face - side * _E, _WING_ZC), (_WING_XC, y_drive, _WING_ZC), 0.08, sections=32)

    # V-shaped yoke from the drive to the panel root, plus a root bar along x
    hub = np.array((_WING_XC, y_drive, _WING_ZC))
    arms = [_rod(hub, (x, y_in, _WING_ZC), 0.02) for x in (x_lo + 0.15, x_hi - 0.15)]
    root_bar = _rod((x_lo + 0.05, y_in, _WING_ZC), (x_hi - 0.05, y_in, _WING_ZC), 0.02)
    yoke = _merge(arms + [root_bar])

    z_back = _WING_ZC - _WING_T / 2
    z_front = _WING_ZC + _WING_T / 2
    if side > 0:
        substrate = _box((x_lo, y_in + 0.016, z_back), (x_hi, y_out, z_front))
    else:
        substrate = _box((x_lo, y_out, z_back), (x_hi, y_in - 0.016, z_front))

    # cell strings: a 4 x 8 grid of modules on the +z face of the substrate
    rows, cols, border, gap = 4, 8, 0.03, 0.015
    sy0, sy1 = sorted((y_in + side * 0.016, y_out))
    cw = (sy1 - sy0 - 2 * border - (cols - 1) * gap) / cols
    ch = (x_hi - x_lo - 2 * border - (rows - 1) * gap) / rows
    cells = []
    for i in range(rows):
        for j in range(cols):
            x0 = x_lo + border + i * (ch + gap)
            y0 = sy0 + border + j * (cw + gap)
            cells.append(_box((x0, y0, z_front - _E), (x0 + ch, y0 + cw, z_front + _CELL_T)))
    return drive, yoke, substrate, _merge(cells)


# ---- the model --------------------------------------------------------------------------------
def build() -> TargetModel:
    """Build the ICESat model (body frame, metres, origin at the centre of mass).

    Returns
    -------
    TargetModel
        32 components; axes as in the module docstring (+x zenith, +y along the solar-array
        axis, telescope boresight -x).
    """
    comps = []

    def add(name, mesh, material, semantic, mass_kg):
        comps.append(Component(name=name, mesh=mesh, material=material, semantic=semantic,
                               mass_kg=float(mass_kg)))

    # -- GLAS (nadir end), 298 kg in total --------------------------------------------------
    add("glas_telescope_housing",
        _square_plate_with_hole(_H, _HOLE_R, 0.0, _X_BENCH), "silver_mli", "instrument", 60.0)
    add("glas_optical_bench",
        _box((_X_BENCH - _E, -_H + _INSET, -_H + _INSET), (_X_GLAS_TOP, _H - _INSET, _H - _INSET)),
        "silver_mli", "instrument", 150.0)
    add("telescope_primary_mirror",
        _primary_mirror(x_rim=0.82, sag=0.05, thickness=0.03 + _E, radius=_TEL_R),
        "aluminium", "instrument", 30.0)
    add("telescope_sunshade",
        _tube((_SHADE_X0, 0, 0), (_X_BENCH + _E, 0, 0), _SHADE_R_IN, _SHADE_R_OUT, sections=96),
        "black_paint", "instrument", 10.0)
    add("telescope_secondary_mirror",
        _rod((0.10, 0, 0), (0.16, 0, 0), 0.085, sections=48), "aluminium", "instrument", 2.0)
    vanes = []
    for k in range(3):
        a = math.pi / 2 + k * 2 * math.pi / 3
        d = np.array((0.0, math.cos(a), math.sin(a)))
        p0 = np.array((0.13, 0, 0)) + d * 0.08
        p1 = np.array((0.13, 0, 0)) + d * (_SHADE_R_IN + 0.002)
        vanes.append(_rod(p0, p1, 0.008, sections=12))
    add("telescope_spider", _merge(vanes), "black_paint", "instrument", 2.0)
    add("laser_beam_expander",
        _rod((-0.05, 0.72, -0.72), (_E, 0.72, -0.72), 0.09, sections=32),
        "black_paint", "instrument", 6.0)
    add("glas_laser_radiator",
        _box((0.15, -0.80, -_H - 0.02), (1.60, 0.80, -_H + _E)), "white_paint", "radiator", 14.0)
    add("glas_electronics_radiator",
        _box((0.20, -0.75, _H - _E), (1.50, 0.75, _H + 0.02)), "white_paint", "radiator", 12.0)
    z_ledge = 0.5 * (_LEDGE_Z + _H)
    add("instrument_star_tracker",
        _star_camera(np.array((_X_GLAS_TOP, -0.40, z_ledge)), (1.0, 0.0, 0.0)),
        "black_paint", "instrument", 6.0)
    add("laser_reference_sensor",
        _star_camera(np.array((_X_GLAS_TOP, 0.35, z_ledge)), (1.0, 0.0, 0.0),
                     body=(0.24, 0.22, 0.22)),
        "black_paint", "instrument", 6.0)

    # -- BCP 2000 bus (zenith end), 672 kg including wings ---------------------------------
    add("bus_body", _box((_X_GLAS_TOP - _E, -_H, -_H), (_X_DECK, _H, _LEDGE_Z)),
        "gold_mli", "bus", 515.0)
    add("bus_radiator_minus_z",
        _box((_X_GLAS_TOP + 0.10, -0.85, -_H - 0.02), (_X_DECK - 0.10, 0.85, -_H + _E)),
        "white_paint", "radiator", 10.0)
    add("bus_radiator_plus_z",
        _box((_X_GLAS_TOP + 0.30, -0.85, _LEDGE_Z - _E), (_X_DECK - 0.10, 0.85, _LEDGE_Z + 0.02)),
        "white_paint", "radiator", 6.0)
    add("separation_ring",
        _tube((_X_DECK - _E, 0, _BUS_ZC), (_X_DECK + 0.06, 0, _BUS_ZC), 0.45, 0.49, sections=64),
        "aluminium", "other", 8.0)
    for i, y in enumerate((0.62, -0.62), start=1):
        choke = _rod((_X_DECK - _E, y, 0.33), (_X_DECK + 0.05, y, 0.33), 0.11, sections=32)
        radome = _rod((_X_DECK + 0.05 - _E, y, 0.33), (_X_DECK + 0.08, y, 0.33), 0.05, sections=32)
        add(f"gps_antenna_{i}", _merge((choke, radome)), "aluminium", "antenna", 1.5)
    add("s_band_omni_zenith",
        _merge((_rod((_X_DECK - _E, 0.0, 0.43), (_X_DECK + 0.02, 0.0, 0.43), 0.05, sections=24),
                _rod((_X_DECK + 0.02 - _E, 0.0, 0.43), (_X_DECK + 0.09, 0.0, 0.43), 0.035, sections=24))),
        "white_paint", "antenna", 1.0)
    add("s_band_omni_nadir",
        _merge((_rod((_E, -0.72, 0.72), (-0.03, -0.72, 0.72), 0.05, sections=24),
                _rod((-0.03 + _E, -0.72, 0.72), (-0.08, -0.72, 0.72), 0.035, sections=24))),
        "white_paint", "antenna", 1.0)
    add("x_band_antenna",
        _merge((_rod((_E, -0.72, -0.72), (-0.03, -0.72, -0.72), 0.10, sections=32),
                _cone((-0.03 + _E, -0.72, -0.72), (-1.0, 0.0, 0.0), 0.08, 0.07, sections=32))),
        "white_paint", "antenna", 3.0)
    lra_base = _rod((_E, 0.72, 0.72), (-0.02, 0.72, 0.72), 0.09, sections=32)
    lra_cubes = [_rod((-0.02 + _E, 0.72 + 0.05 * math.cos(a), 0.72 + 0.05 * math.sin(a)),
                      (-0.045, 0.72 + 0.05 * math.cos(a), 0.72 + 0.05 * math.sin(a)), 0.022,
                      sections=12)
                 for a in np.arange(6) * math.pi / 3]
    lra_cubes.append(_rod((-0.02 + _E, 0.72, 0.72), (-0.045, 0.72, 0.72), 0.022, sections=12))
    add("slr_retroreflector", _merge([lra_base] + lra_cubes), "aluminium", "other", 1.0)
    for i, (y, tilt) in enumerate(((-0.62, -1.0), (0.62, 1.0)), start=1):
        # canted 30 deg off zenith, away from each other and towards -z
        bore = np.array((math.cos(math.radians(30)), tilt * 0.25, -0.45))
        add(f"bus_star_tracker_{i}",
            _star_camera(np.array((_X_DECK, y, -0.72)), bore, body=(0.16, 0.16, 0.12),
                         shade_len=0.08, shade_r=(0.055, 0.07)),
            "black_paint", "instrument", 4.0)
    thrusters = [_cone((_X_DECK - 0.02, y, z), (1.0, 0.35 * np.sign(y), 0.35 * np.sign(z - _BUS_ZC)),
                       0.03, 0.08, sections=16)
                 for y in (-0.88, 0.88) for z in (-0.88, 0.48)]
    add("hydrazine_thrusters", _merge(thrusters), "titanium", "thruster", 2.0)

    # -- solar array wings (estimated size, see Notes) --------------------------------------
    for side, tag in ((1, "plus_y"), (-1, "minus_y")):
        drive, yoke, substrate, cells = _solar_wing(side)
        add(f"solar_array_drive_{tag}", drive, "aluminium", "other", 6.0)
        add(f"solar_array_yoke_{tag}", yoke, "aluminium", "boom", 4.0)
        add(f"solar_panel_substrate_{tag}", substrate, "aluminium", "solar_panel", 35.0)
        add(f"solar_panel_cells_{tag}", cells, "solar_cell", "solar_panel", 12.0)

    return TargetModel(
        name="icesat",
        components=centre_on_mass(comps),
        description=("ICESat (NASA/Ball BCP 2000 + GLAS, 2003): 3.1 x 1.9 x 1.9 m stack, 1 m "
                     "telescope, two solar wings; dimensions from Wikipedia/Gunter, NASA GCMD "
                     "GLAS, CSR/UT (wing size estimated from the 640 W power budget)"),
        metadata={"launch_mass_kg": LAUNCH_MASS_KG, "glas_mass_kg": GLAS_MASS_KG,
                  "axes": "+x zenith, +y solar-array axis, +z right-handed; telescope looks -x"},
    )
