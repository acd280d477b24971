"""Cassini–Huygens (NASA/ESA/ASI, launched 1997) as launched, with boom and antennas deployed.

Built procedurally from trimesh primitives (cylinders, boxes, cones and revolved profiles);
nothing is read from disk.

Body frame
----------
Axes are parallel to Cassini's own structural frame ``CASSINI_SC_COORD`` [NAIF-FK]:

* ``-Z`` is the high-gain-antenna boresight (the dish is "on top"), ``+Z`` points from the
  electronics bus towards the propulsion module and the main engines;
* ``-X`` points towards the Huygens probe (and the fields-and-particles pallet); the remote
  sensing pallet is on the ``+X`` side and its instruments look along ``-Y``;
* ``+Y`` runs along the magnetometer boom.

The origin is the centre of mass (launch configuration, full tanks, probe attached), not the
frame kernel's bus/upper-module joint. In the code below heights ``h`` are measured upwards
(towards the dish, ``h = -z``) from that joint before the final shift to the centre of mass.

Dimensions and sources
----------------------
==============================  ===================================  =========================
Part                            Dimension used                       Source
==============================  ===================================  =========================
Overall height                  6.75 m (nozzle exit to LGA1 top)     [JPL-SC] ">6.7 m high",
                                                                     [ENG] "6.8 m high"
Overall width (no boom/ants.)   4.0 m (HGA)                          [JPL-SC] ">4 m wide"
High-gain antenna dish          4.0 m diameter, fixed, on top        [ESA-ENG] "four-meter"
Stack order                     HGA / UEM / 12-bay bus / propulsion  [ESA-ENG] "nearly
                                module / LEM, pallets halfway up     cylindrical stack"
Magnetometer boom               11 m, along +Y; fluxgate at 5.5 m,   [JPL-MAG], [PH-RW]
                                V/SHM at the tip                     "11-meter Magnetometer
                                                                     Boom"
RPWS electric antennas          3 x 10 m monopoles; two in a 120 deg [NAIF-FK] RPWS section
                                "V" about +Y tilted 37 deg towards
                                the HGA, one 37 deg from +Z in Y-Z
RTGs (3, GPHS-RTG)              1.14 m long, 0.422 m over the fins,  [GPHS]
                                57 kg each
Huygens probe                   2.7 m across (front shield), 60 deg  [ESA-HUY], [NSSDC-HUY]
                                sphere-cone, descent module 1.3 m    (1.3 m DM)
Huygens mass                    318 kg probe + 30 kg support equip.  [ESA-HUY2]
Orbiter dry / propellant        2 150 kg / 3 132 kg                  [ENG], [WINTER]
Main engines                    2 x 445 N, side by side under the    [PH-RW], [BBC]
                                lower equipment module
Remote sensing pallet           +X side, boresights -Y               [NAIF-FK] ISS/VIMS notes
Fields & particles pallet       -X side                              [NAIF-FK] CAPS note
LGA1 / LGA2                     LGA1 along -Z on the subreflector,   [NAIF-FK] antenna frames
                                LGA2 looks along -X
==============================  ===================================  =========================

Estimated (no published figure found; proportions from launch photographs and the NASA
3-D model): 12-bay bus 2.1 m across corners x 0.55 m; upper equipment module 1.3 m x 0.55 m;
propulsion module 1.44-1.60 m diameter x 2.8 m (two stacked tanks, gold MLI); lower
equipment module 1.7 m x 0.4 m; HGA depth 0.6 m (f = 1.65 m), Cassegrain subreflector
0.66 m at 1.3 m above the vertex; engine length 0.7 m incl. gimbal, nozzle exit 0.42 m;
Huygens axial length 1.04 m (front-shield nose radius 1.25 m); RTG layout (one at +X, one
each at +/-Y, axes horizontal at 45 deg to the radius, 1.45 m out, level with the fuel tank).

References
----------
[JPL-SC]   NASA/JPL, "Cassini Spacecraft and Huygens Probe" fact sheet (1997),
           https://www.scribd.com/document/46776076/Cassini-Spacecraft-and-Huygens-Probe
[ENG]      "The Cassini Spacecraft", engineering.com library (orbiter 2 150 kg, propellant
           3 132 kg, 6.8 m x 4 m).
[WINTER]   C. Winter, "The Cassini Mission to Saturn: The Spacecraft",
           http://chris-winter.com/NASA/Cassini/CassCrft.html (6.8 m, 4 m HGA, masses).
[ESA-ENG]  ESA, "Cassini-Huygens: Engineering", http://sci.esa.int/cassini-huygens/35026-engineering/
[ESA-HUY]  ESA, "Huygens spacecraft", https://www.esa.int/Science_Exploration/Space_Science/
           Cassini-Huygens/Huygens_spacecraft ("2.7 metres across").
[ESA-HUY2] ESA, Huygens probe system (318 kg probe, 30 kg PSE),
           http://sci.esa.int/science-e/www/object/printfriendly.cfm?fobjectid=47052
[NSSDC-HUY] NASA NSSDC, "Huygens", http://nssdc.gsfc.nasa.gov/planetary/huygens.html
[JPL-MAG]  NASA/JPL, Cassini MAG, https://www2.jpl.nasa.gov/basics/cassini/mag.html
           (sensors at 5.5 m and 11 m).
[PH-RW]    "Passage to a Ringed World", NASA SP-533 (1997), ch. 8 orbiter figure.
[BBC]      BBC News, "The Spacecraft" (engines, one a back-up).
[GPHS]     GPHS-RTG (Wikipedia, after G. L. Bennett, AIAA 2006-4191): 0.422 m x 1.14 m, 57 kg.
[NAIF-FK]  NAIF/JPL, Cassini frames kernel cas_v37.tf (spacecraft frame, antenna, ISS,
           VIMS, CAPS and RPWS sections).
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from ..model import Component, TargetModel, centre_on_mass

__all__ = ["build"]

# --- published figures [m, kg] (see the module docstring for sources) ---------------------
HGA_DIAMETER_M = 4.0
MAG_BOOM_LENGTH_M = 11.0
RPWS_ANTENNA_LENGTH_M = 10.0
RPWS_TILT_DEG = 37.0
RTG_LENGTH_M = 1.14
RTG_DIAMETER_M = 0.422
RTG_MASS_KG = 57.0
HUYGENS_DIAMETER_M = 2.7
HUYGENS_DM_DIAMETER_M = 1.3
HUYGENS_PROBE_MASS_KG = 318.0
HUYGENS_PSE_MASS_KG = 30.0
PROPELLANT_MASS_KG = 3132.0
ORBITER_DRY_MASS_KG = 2150.0

# --- estimated layout (heights h are upwards from the bus / upper-module joint) -----------
BUS_R_CORNER = 1.05          # 12-bay bus, across corners 2.1 m
BUS_H = 0.55
UEM_R, UEM_H = 0.65, 0.55
PM_TOP, PM_BOTTOM = -BUS_H, -3.35
LEM_R, LEM_BOTTOM = 0.85, -3.75
HGA_F = 1.65                 # focal length: depth 0.6 m at the rim
HGA_VERTEX_H = 0.62
HGA_T = 0.04                 # dish shell thickness
SUB_H = 1.92                 # subreflector centre height
ENGINE_Y = 0.3
HUYGENS_H = -1.95            # probe axis height (level with the tank waist)
HUYGENS_BACK_X = -0.95       # back-cover top plane
RTG_RADIUS, RTG_H = 1.45, -2.95
MAG_BOOM_H = 0.30
RPWS_BASE = (-0.30, 1.25, 0.50)   # bracket on the +Y side of the boom canister


def _p(x, y, h):
    """Point in the Cassini frame from a height measured upwards (towards the HGA) [m]."""
    return np.array([x, y, -h], dtype=float)


def _frame_to(axis, origin):
    """Homogeneous transform taking +z to ``axis`` and the origin to ``origin``."""
    axis = np.asarray(axis, float)
    axis = axis / np.linalg.norm(axis)
    T = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], axis)
    T[:3, 3] = origin
    return T


def _revolved(profile, sections, axis=(0.0, 0.0, 1.0), origin=(0.0, 0.0, 0.0)):
    """Closed solid of revolution from a (radius, axial) profile, outward winding."""
    p = np.asarray(profile, float)
    x, y = p[:, 0], p[:, 1]
    if np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y) < 0.0:   # make it counter-clockwise
        p = p[::-1]
    mesh = trimesh.creation.revolve(p, sections=sections)
    mesh.apply_transform(_frame_to(axis, origin))
    return mesh


def _rod(p0, p1, radius, sections=12):
    return trimesh.creation.cylinder(radius=radius, segment=np.array([p0, p1], float), sections=sections)


def _box(extents, centre, rotation=None):
    T = np.eye(4)
    if rotation is not None:
        T[:3, :3] = rotation
    T[:3, 3] = centre
    return trimesh.creation.box(extents=extents, transform=T)


def _rot_z(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _union(meshes):
    return trimesh.util.concatenate(list(meshes))


# ------------------------------------------------------------------ high-gain antenna ----
def _hga():
    up = (0.0, 0.0, -1.0)
    r = HGA_DIAMETER_M / 2.0 * np.linspace(0.0, 1.0, 18) ** 0.8
    front = HGA_VERTEX_H + r ** 2 / (4.0 * HGA_F)
    back = front - HGA_T
    # the axis of revolution is -z, so profile heights are h (= -z) directly
    profile = [(0.0, back[0])] + list(zip(r[1:], back[1:])) + list(zip(r[::-1], front[::-1]))
    dish = _revolved(profile, 64, axis=up)

    support = _revolved([(0.0, 0.55), (0.62, 0.55), (0.75, 0.60), (0.0, 0.60)], 48, axis=up)

    feed = _revolved([(0.0, HGA_VERTEX_H - 0.01), (0.15, HGA_VERTEX_H - 0.01), (0.15, 1.02),
                      (0.19, 1.15), (0.0, 1.15)], 32, axis=up)
    sub = _revolved([(0.0, SUB_H - 0.06), (0.33, SUB_H + 0.01), (0.33, SUB_H + 0.03),
                     (0.0, SUB_H + 0.05)], 48, axis=up)
    lga1 = _revolved([(0.0, SUB_H + 0.05), (0.09, SUB_H + 0.05), (0.14, SUB_H + 0.33),
                      (0.0, SUB_H + 0.38)], 24, axis=up)

    # three bipods from the dish surface (r = 1.5 m) to the subreflector rim
    rods = []
    r_base = 1.5
    h_base = HGA_VERTEX_H + r_base ** 2 / (4.0 * HGA_F)
    for k in range(3):
        a = math.radians(30.0 + 120.0 * k)
        top = _p(0.30 * math.cos(a), 0.30 * math.sin(a), SUB_H + 0.01)
        for da in (-0.16, 0.16):
            base = _p(r_base * math.cos(a + da), r_base * math.sin(a + da), h_base)
            rods.append(_rod(base, top, 0.022))
    struts = _union(rods)
    return dish, support, feed, sub, lga1, struts


# ------------------------------------------------------------------ central stack --------
def _stack():
    bus = trimesh.creation.cylinder(radius=BUS_R_CORNER, height=BUS_H, sections=12)
    bus.apply_transform(np.vstack([np.hstack([_rot_z(math.radians(15.0)), _p(0, 0, -BUS_H / 2)[:, None]]),
                                   [0, 0, 0, 1]]))          # flats face +-X and +-Y

    apothem = BUS_R_CORNER * math.cos(math.radians(15.0))
    louvers = []
    for deg in (30, 60, 150, 210, 240, 270, 300, 330):
        a = math.radians(deg)
        c = _p((apothem + 0.012) * math.cos(a), (apothem + 0.012) * math.sin(a), -BUS_H / 2)
        louvers.append(_box((0.024, 0.40, 0.40), c, _rot_z(a)))
    louvers = _union(louvers)

    uem = trimesh.creation.cylinder(radius=UEM_R, segment=[_p(0, 0, 0.0), _p(0, 0, UEM_H)], sections=32)

    # propulsion module: gold-wrapped shell over two stacked tanks (oxidizer above, fuel below)
    h = np.linspace(PM_BOTTOM, PM_TOP, 57)
    s = (h - PM_BOTTOM) / (PM_TOP - PM_BOTTOM)
    r = 0.72 + 0.08 * np.abs(np.sin(2.0 * math.pi * s)) ** 0.6
    r[0] = r[-1] = 0.72
    pm = _revolved([(0.0, PM_BOTTOM)] + list(zip(r, h)) + [(0.0, PM_TOP)], 48, axis=(0, 0, -1))

    lem = trimesh.creation.cylinder(radius=LEM_R, segment=[_p(0, 0, LEM_BOTTOM), _p(0, 0, PM_BOTTOM)],
                                    sections=24)
    return bus, louvers, uem, pm, lem


def _engines():
    down = (0.0, 0.0, 1.0)
    engines = []
    top = LEM_BOTTOM
    for y in (-ENGINE_Y, ENGINE_Y):
        gimbal = trimesh.creation.cylinder(radius=0.08, segment=[_p(0, y, top), _p(0, y, top - 0.2)],
                                           sections=24)
        # bell: a thin shell from the throat (r 0.06) to the exit (r 0.21), 0.5 m long
        s = np.linspace(0.0, 1.0, 12)
        r_in = 0.06 + 0.15 * np.sqrt(s)
        depth = 0.5 * s
        outer = list(zip(r_in + 0.012, depth))
        inner = list(zip(r_in[::-1], depth[::-1]))
        bell = _revolved(outer + inner + outer[:1], 32, axis=down, origin=_p(0, y, top - 0.2))
        engines.append(_union([gimbal, bell]))

    # retracted (stowed) articulated engine cover: folded bundle beside the engines
    cover = _rod(_p(0.55, -0.45, LEM_BOTTOM - 0.11), _p(0.55, 0.45, LEM_BOTTOM - 0.11), 0.11, 24)

    rcs = []
    for k in range(4):
        a = math.radians(45.0 + 90.0 * k)
        c = _p(0.94 * math.cos(a), 0.94 * math.sin(a), -3.55)
        rcs.append(_box((0.2, 0.18, 0.18), c, _rot_z(a)))
        nz = trimesh.creation.cone(0.04, 0.08, sections=12)     # apex +z: nozzles fire along +z/-z
        for sign in (1.0, -1.0):
            T = _frame_to((0, 0, -sign), c + np.array([0, 0, sign * 0.17]))
            rcs.append(nz.copy().apply_transform(T))
    rcs = _union(rcs)
    return engines, cover, rcs


# ------------------------------------------------------------------ RTGs ------------------
def _rtgs():
    parts = []
    mounts = []
    for phi_deg in (0.0, 90.0, -90.0):
        phi = math.radians(phi_deg)
        radial = np.array([math.cos(phi), math.sin(phi), 0.0])
        tangential = np.array([-math.sin(phi), math.cos(phi), 0.0])
        axis = (radial + tangential) / math.sqrt(2.0)
        centre = _p(0, 0, RTG_H) + RTG_RADIUS * radial
        half = RTG_LENGTH_M / 2.0
        housing = _union([
            _rod(centre - axis * (half - 0.04), centre + axis * (half - 0.04), 0.13, 32),
            _rod(centre - axis * half, centre - axis * (half - 0.04), 0.16, 32),   # end domes/flanges
            _rod(centre + axis * (half - 0.04), centre + axis * half, 0.16, 32),
        ])
        T = _frame_to(axis, centre)
        fins = []
        r_tip = RTG_DIAMETER_M / 2.0
        for k in range(8):
            a = 2.0 * math.pi * k / 8.0
            fin_c = np.array([math.cos(a), math.sin(a), 0.0]) * (0.125 + r_tip) / 2.0
            fin = _box((r_tip - 0.125, 0.012, RTG_LENGTH_M - 0.14), fin_c, _rot_z(a))
            fins.append(fin.apply_transform(T))
        parts.append(_union([housing] + fins))      # black finned converter, one mesh per RTG
        # V-bracket from the fuel-tank section of the propulsion module to the RTG middle
        for dh in (0.25, -0.25):
            root = _p(0, 0, RTG_H + dh) + 0.74 * radial
            mounts.append(_rod(root, centre - 0.10 * radial, 0.025))
    return parts, _union(mounts)


# ------------------------------------------------------------------ booms and antennas ----
def _magnetometer():
    can_c = (0.0, 0.95)
    canister = trimesh.creation.cylinder(radius=0.28, segment=[_p(*can_c, 0.0), _p(*can_c, 0.55)], sections=32)
    y0 = can_c[1] + 0.20                            # root just inside the canister wall
    circ = 0.20                                      # triangular lattice, side 0.35 m
    corners = [np.array([circ * math.cos(a), 0.0, -circ * math.sin(a)])
               for a in (math.radians(90.0), math.radians(210.0), math.radians(330.0))]
    centre0 = _p(0.0, y0, MAG_BOOM_H)
    rods = [_rod(centre0 + c, centre0 + c + [0, MAG_BOOM_LENGTH_M, 0], 0.015) for c in corners]
    n_bays = 22
    ys = np.linspace(0.0, MAG_BOOM_LENGTH_M, n_bays + 1)
    for i, yy in enumerate(ys):
        for j in range(3):
            a, b = corners[j], corners[(j + 1) % 3]
            rods.append(_rod(centre0 + a + [0, yy, 0], centre0 + b + [0, yy, 0], 0.008))
            if i < n_bays:
                rods.append(_rod(centre0 + a + [0, yy, 0], centre0 + b + [0, ys[i + 1], 0], 0.006))
    boom = _union(rods)
    fgm = _box((0.16, 0.16, 0.16), centre0 + [0, MAG_BOOM_LENGTH_M / 2.0, 0])
    vshm = _rod(centre0 + [0, MAG_BOOM_LENGTH_M, 0], centre0 + [0, MAG_BOOM_LENGTH_M + 0.25, 0], 0.11, 24)
    return canister, boom, fgm, vshm


def _rpws():
    base = _p(*RPWS_BASE)
    t = math.radians(RPWS_TILT_DEG)
    dirs = {
        "rpws_antenna_x_plus": np.array([math.sin(math.radians(60)), 0.5 * math.cos(t), -0.5 * math.sin(t)]),
        "rpws_antenna_x_minus": np.array([-math.sin(math.radians(60)), 0.5 * math.cos(t), -0.5 * math.sin(t)]),
        "rpws_antenna_z_plus": np.array([0.0, math.sin(t), math.cos(t)]),
    }
    can = _p(0.0, 0.95, RPWS_BASE[2])                  # canister axis at the bracket height
    towards = (base - can) / np.linalg.norm(base - can)
    bracket = _union([_box((0.16, 0.16, 0.16), base, _rot_z(math.atan2(towards[1], towards[0]))),
                      _rod(can + 0.26 * towards, base, 0.03)])
    ants = {name: _rod(base + 0.06 * d, base + (0.06 + RPWS_ANTENNA_LENGTH_M) * d, 0.0143, 12)
            for name, d in dirs.items()}
    return bracket, ants


# ------------------------------------------------------------------ Huygens ---------------
def _huygens():
    axis = (-1.0, 0.0, 0.0)
    origin = _p(HUYGENS_BACK_X, 0.0, HUYGENS_H)
    R = HUYGENS_DIAMETER_M / 2.0
    s_rim = 0.45
    back = _revolved([(0.0, 0.0), (HUYGENS_DM_DIAMETER_M / 2.0, 0.0), (R, s_rim - 0.03), (R, s_rim),
                      (0.0, s_rim)], 64, axis=axis, origin=origin)
    # 60 deg half-angle sphere-cone, nose radius 1.25 m
    half = math.radians(60.0)
    rn = 1.25
    r_t = rn * math.cos(half)
    s_t = s_rim + (R - r_t) / math.tan(half)
    s_nose = s_t + rn * (1.0 - math.sin(half))
    centre_s = s_nose - rn
    arc = [(rn * math.cos(b), centre_s + rn * math.sin(b)) for b in np.linspace(half, math.pi / 2, 8)]
    front = _revolved([(0.0, s_rim), (R, s_rim)] + arc[:-1] + [(0.0, s_nose)], 64, axis=axis,
                      origin=origin)
    pse = _union([
        trimesh.creation.cylinder(radius=0.32, segment=[_p(-0.70, 0, HUYGENS_H), _p(HUYGENS_BACK_X, 0, HUYGENS_H)],
                                  sections=32),
    ] + [_rod(_p(-0.72, 0.55 * math.cos(a), HUYGENS_H + 0.55 * math.sin(a)),
              _p(HUYGENS_BACK_X - 0.002, 0.62 * math.cos(a), HUYGENS_H + 0.62 * math.sin(a)), 0.025)
         for a in np.radians([90.0, 210.0, 330.0])])
    return back, front, pse


# ------------------------------------------------------------------ science pallets -------
def _remote_sensing():
    plate_x = BUS_R_CORNER * math.cos(math.radians(15.0))
    pallet = _union([
        _box((0.06, 1.30, 1.30), _p(plate_x + 0.03, -0.10, -0.70)),
        _box((plate_x - 0.70, 0.9, 0.5), _p((plate_x + 0.70) / 2.0 + 0.02, -0.10, -1.05)),   # standoff to PM
    ])
    x0 = plate_x + 0.06
    minus_y = (0.0, -1.0, 0.0)
    nac = _revolved([(0.0, 0.0), (0.11, 0.0), (0.11, 0.95), (0.0, 0.95)], 24, axis=minus_y,
                    origin=_p(x0 + 0.12, 0.13, -0.28))
    wac = _revolved([(0.0, 0.0), (0.09, 0.0), (0.09, 0.50), (0.0, 0.50)], 24, axis=minus_y,
                    origin=_p(x0 + 0.10, -0.12, -0.58))
    cameras = _union([nac, wac])
    vims = _union([_box((0.36, 0.40, 0.40), _p(x0 + 0.18, -0.48, -1.02)),
                   _revolved([(0.0, 0.0), (0.09, 0.0), (0.12, 0.12), (0.0, 0.12)], 24, axis=minus_y,
                             origin=_p(x0 + 0.20, -0.68, -1.02))])
    cirs = _revolved([(0.0, 0.0), (0.26, 0.0), (0.26, 0.62), (0.0, 0.62)], 32, axis=minus_y,
                     origin=_p(x0 + 0.27, 0.50, -1.0))
    uvis = _box((0.22, 0.48, 0.22), _p(x0 + 0.11, 0.28, -0.60))
    return pallet, cameras, vims, cirs, uvis


def _fields_particles():
    plate_x = -BUS_R_CORNER * math.cos(math.radians(15.0))
    pallet = _box((0.06, 1.20, 0.50), _p(plate_x - 0.03, 0.0, -0.27))
    x0 = plate_x - 0.06
    caps = _box((0.36, 0.40, 0.34), _p(x0 - 0.18, -0.30, -0.24))
    mimi = _union([
        _rod(_p(x0, 0.22, -0.20), _p(x0 - 0.30, 0.22, -0.20), 0.11, 24),
        _box((0.24, 0.26, 0.22), _p(x0 - 0.12, 0.45, -0.30)),
    ])
    lga2 = _revolved([(0.0, 0.0), (0.06, 0.0), (0.11, 0.22), (0.0, 0.22)], 24, axis=(-1.0, 0.0, 0.0),
                     origin=_p(-LEM_R * math.cos(math.pi / 24) + 0.005, 0.0, (PM_BOTTOM + LEM_BOTTOM) / 2.0))
    return pallet, caps, mimi, lga2


def build() -> TargetModel:
    """Cassini–Huygens in its launch configuration (boom and RPWS antennas deployed)."""
    dish, support, feed, sub, lga1, struts = _hga()
    bus, louvers, uem, pm, lem = _stack()
    (engine_a, engine_b), cover, rcs = _engines()
    rtg_parts, rtg_mounts = _rtgs()
    canister, boom, fgm, vshm = _magnetometer()
    rpws_bracket, rpws = _rpws()
    hback, hfront, pse = _huygens()
    rsp, cameras, vims, cirs, uvis = _remote_sensing()
    fpp, caps, mimi, lga2 = _fields_particles()

    flat = math.radians(20.0)
    C = Component
    comps = [
        C("high_gain_antenna", dish, "dish", "dish", 80.0),
        C("hga_support_ring", support, "white_paint", "truss", 10.0),
        C("hga_feed", feed, "white_paint", "antenna", 6.0),
        C("hga_subreflector", sub, "dish", "antenna", 6.0),
        C("hga_subreflector_struts", struts, "white_paint", "truss", 6.0),
        C("low_gain_antenna_1", lga1, "white_paint", "antenna", 2.0),
        C("upper_equipment_module", uem, "gold_mli", "module", 180.0),
        C("electronics_bus", bus, "gold_mli", "bus", 640.0, flat),
        C("bus_louvers", louvers, "aluminium", "radiator", 12.0, flat),
        C("propulsion_module", pm, "gold_mli", "module", PROPELLANT_MASS_KG),   # dry share set below
        C("lower_equipment_module", lem, "black_paint", "module", 160.0, flat),
        C("main_engine_prime", engine_a, "titanium", "engine", 8.0),
        C("main_engine_backup", engine_b, "titanium", "engine", 8.0),
        C("main_engine_cover", cover, "black_paint", "other", 6.0),
        C("rcs_thruster_clusters", rcs, "black_paint", "thruster", 16.0, flat),
    ]
    for k, rtg in enumerate(rtg_parts, start=1):
        comps.append(C(f"rtg_{k}", rtg, "black_paint", "rtg", RTG_MASS_KG, flat))
    comps += [
        C("rtg_mounts", rtg_mounts, "aluminium", "truss", 15.0),
        C("magnetometer_canister", canister, "gold_mli", "boom", 20.0),
        C("magnetometer_boom", boom, "aluminium", "boom", 25.0),
        C("magnetometer_fluxgate", fgm, "white_paint", "instrument", 3.0, flat),
        C("magnetometer_vshm", vshm, "white_paint", "instrument", 3.0),
        C("rpws_bracket", rpws_bracket, "aluminium", "antenna", 1.0, flat),
    ]
    comps += [C(name, mesh, "aluminium", "antenna", 1.5) for name, mesh in rpws.items()]
    comps += [
        C("remote_sensing_pallet", rsp, "black_paint", "instrument", 60.0, flat),
        C("iss_cameras", cameras, "white_paint", "instrument", 58.0),
        C("vims", vims, "black_paint", "instrument", 37.0, flat),
        C("cirs", cirs, "gold_mli", "instrument", 43.0),
        C("uvis", uvis, "black_paint", "instrument", 15.0, flat),
        C("fields_particles_pallet", fpp, "aluminium", "instrument", 40.0, flat),
        C("caps", caps, "black_paint", "instrument", 23.0, flat),
        C("mimi_lemms", mimi, "aluminium", "instrument", 16.0),
        C("low_gain_antenna_2", lga2, "white_paint", "antenna", 2.0),
        C("huygens_probe_support", pse, "aluminium", "truss", HUYGENS_PSE_MASS_KG),
        C("huygens_back_cover", hback, "gold_mli", "probe", HUYGENS_PROBE_MASS_KG - 80.0),
        C("huygens_front_shield", hfront, "gold_mli", "heat_shield", 80.0),
    ]
    # the propulsion module's dry share closes the published orbiter dry mass
    probe = {"huygens_probe_support", "huygens_back_cover", "huygens_front_shield"}
    dry_others = sum(c.mass_kg for c in comps if c.name not in probe | {"propulsion_module"})
    comps = [C(c.name, c.mesh, c.material, c.semantic, PROPELLANT_MASS_KG + ORBITER_DRY_MASS_KG - dry_others,
               c.crease_angle_rad) if c.name == "propulsion_module" else c for c in comps]
    comps = centre_on_mass(comps)
    return TargetModel(
        name="cassini",
        components=comps,
        description=("Cassini-Huygens orbiter and probe at launch, boom and RPWS antennas deployed; "
                     "6.75 m tall, 4 m HGA, 11 m boom (NASA/JPL, ESA, NAIF frames kernel)."),
        metadata={"frame": "CASSINI_SC_COORD axes: -Z HGA boresight, +Z engines, -X Huygens, "
                           "+Y magnetometer boom; origin at the centre of mass"},
    )
