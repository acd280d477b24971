"""SpaceX Crew Dragon (Dragon 2) with its trunk, nose cone open as in orbit.

Body frame (metres, origin at the centre of mass after :func:`centre_on_mass`):

- **+x** along the symmetry axis, from the trunk towards the capsule and out through the
  docking adapter (the docking direction);
- **+z** towards the side hatch; the nose cone is hinged on this side and swings open over it;
  the trunk's body-mounted solar cells face **-z** (the non-hatch side) and its radiators +z;
- **+y** completes the right-handed frame.

Azimuth ``az`` below is measured about +x from +z towards -y (so ``az = 90 deg`` is -y).
Four fins sit at the aft end of the trunk at ``az = 0, 90, 180, 270 deg``; two of them lie on
the boundaries between the solar-cell half and the radiator half, the others in the middle of
each half. The four SuperDraco pods are at ``az = 45 + k*90 deg``, so the hatch lies between two
of them. Heights quoted in the table are measured from the heat-shield apex, before centring.

Key dimensions and sources
--------------------------
========================================  ==============================  ======================
part                                      dimension (model)               source
========================================  ==============================  ======================
whole vehicle, capsule + trunk            8.1 m tall (nose cone closed)   [1] SpaceX, [2], [3]
capsule maximum diameter                  4.0 m                           [1] SpaceX, [2]
capsule height incl. closed nose cone     4.4 m (4.4-4.5 published)      [2] 4.5 m; [4] 4.4 m
sidewall angle (cone half-angle)          15 deg                          [2], [5], [11]
trunk diameter                            3.66 m                          [4] SpaceX CRS-6 press kit
trunk height (below the capsule)          3.7 m = 8.1 - 4.4, see note     [1], [4], [6]
trunk cells / radiator split              one half cells, other half      [1] SpaceX, [7], [8]
                                          radiator; cells on non-hatch
                                          side
aerodynamic fins                          4 at the aft end of the trunk   [7], [9]
SuperDraco engines                        4 pods x 2 engines on sidewall  [1], [2], [7]
Draco thrusters                           16 (grouping estimated: 12 side [1] SpaceX (count)
                                          in 4 groups of 3, 4 forward)
windows                                   4 + 1 in the hatch              [10]
heat shield                               PICA-X, full base diameter      [10]
capsule dry mass                          7,700 kg                        [2]
propellant                                2,562 kg                        [2]
launch mass (capsule + trunk)             12,262 kg model vs 12,500 kg    [2]
trunk mass                                2,000 kg (brief: 1.5-2 t;       [2] (12,500 - 7,700
                                          estimate)                       - 2,562 = 2,238 kg)
========================================  ==============================  ======================

Note on the trunk height: the Dragon 1 trunk was 2.8 m tall [4], but Crew Dragon's trunk holds
37 m^3 against Dragon 1's 14 m^3 [1], [5], and the published 8.1 m stack height [1] less the
4.4-4.5 m capsule [2], [4] leaves about 3.6-3.7 m of trunk below the heat shield; Dragon 1's
*extended* trunk was 4.3 m [6]. The trunk cylinder here runs from the capsule interface (where
it meets the heat shield, 0.36 m above its apex) 4.06 m down.

Estimated without a source (proportions taken from photographs): the heat-shield curvature
(spherical cap, radius 1.2 x diameter as on Apollo), nose-cone profile (blunt dome, 0.85 m high)
and opening angle (105 deg about a hinge at the rim), docking adapter (1.4 m collar, IDSS soft-
capture ring with three guide petals), fin planform (1.4 m root chord, 0.55 m tip chord, 0.55 m
span, swept leading edge), pod, window and Draco-port sizes.

References
----------
[1] SpaceX, "Dragon" vehicle page, https://www.spacex.com/vehicles/dragon/ (height 8.1 m,
    diameter 4 m, trunk volume 37 m^3, "one half of the trunk is covered in solar panels",
    16 Draco thrusters, 8 SuperDracos).
[2] Wikipedia, "SpaceX Dragon 2", https://en.wikipedia.org/wiki/SpaceX_Dragon_2 (infobox:
    height 4.5 m capsule only / 8.1 m with trunk, diameter 4 m, width 3.7 m, sidewall angle
    15 deg, dry mass 7,700 kg, launch mass 12,500 kg, propellant 2,562 kg).
[3] Spaceflight Now, "Photos: Crew Dragon mated with Falcon 9 rocket", 2020-05-21,
    https://spaceflightnow.com/2020/05/21/photos-crew-dragon-mated-with-falcon-9-rocket/
    (8.1 m tall, about 4 m in diameter, body-mounted solar arrays, stabilisation fins).
[4] SpaceX/NASA CRS-6 press kit, 2015, p. 20,
    https://www.yumpu.com/en/document/view/54861214/spacex-nasa-crs-6-presskit/20
    (Dragon 4.4 m tall, 3.66 m diameter; trunk 2.8 m tall, 3.66 m wide).
[5] SpaceX Dragon page as archived 2017-04-12,
    https://web.archive.org/web/20170412113142/https://www.spacex.com/dragon
    (sidewall angle 15 deg, height with trunk 7.2 m and trunk payload volume 14 m^3: Dragon 1).
[6] West East Space, "SpaceX Dragon - side by side", 2019,
    https://westeastspace.com/2019/09/02/spacex-dragon-side-by-side/
    (Dragon 1 extended trunk 4.3 m).
[7] Spaceflight Insider, "Meet Crew Dragon: narrated tour of design features", 2020-05-26,
    https://www.spaceflightinsider.com/space-flight-news/
    meet-crew-dragon-narrated-tour-of-design-features-design-history/
    (four pairs of SuperDracos on the sidewalls; trunk with body-mounted solar cells and
    radiators; four aerodynamic fins).
[8] Parabolic Arc, "SpaceX's Crew Dragon spacecraft and Falcon 9 rocket prepped for flight",
    2018-12-20, http://parabolicarc.com/2018/12/20/
    spacexs-crew-dragon-spacecraft-falcon-9-rocket-prepped-flight/
    (reader comments: half solar cells, half radiators; cells on the non-hatch side).
[9] TIME for Kids, "A Look at the Dragon", 2021, https://www.timeforkids.com/g34/look-dragon/
    (four fins at the base of the trunk; half of the trunk covered in solar panels).
[10] Graphic News, "Flight of the Crew Dragon", 2020,
     http://46.235.172.94/Archive/arch-38500-38999/GN38813T_words_EN.txt
     (PICA-X heat shield, five windows, nose cone covering the docking hatch, four pairs of
     SuperDracos).
[11] r/SpaceX API Dragon record, https://raw.githubusercontent.com/api-evangelist/spacex/
     refs/heads/main/examples/spacex-getdragon-example.json (heat shield PICA-X,
     sidewall_angle_deg 15).
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from ..model import Component, TargetModel, centre_on_mass

__all__ = ["build"]

# --- published / derived dimensions [m] -------------------------------------------------
HEIGHT_CLOSED_M = 8.1          # [1] capsule (nose cone closed) + trunk
CAPSULE_DIAMETER_M = 4.0       # [1], [2]
CAPSULE_HEIGHT_M = 4.4         # [2] 4.5 m, [4] 4.4 m
SIDEWALL_ANGLE_DEG = 15.0      # [2], [5], [11]
TRUNK_DIAMETER_M = 3.66        # [4]

# --- construction parameters (build frame: axis along Z, hatch towards +X) --------------
_SECTIONS = 64                 # around large bodies of revolution
_HS_RIM_R = 1.95               # end of the spherical heat-shield face
_HS_EDGE_R = 1.97              # rounded edge of the heat shield
_HS_TOP_Z = 0.43               # heat shield / capsule interface plane
_HS_SPHERE_R = 1.2 * CAPSULE_DIAMETER_M   # Apollo-like R/D
_R_MAX = CAPSULE_DIAMETER_M / 2.0
_WALL_Z0 = 0.55                # start of the 15 deg conical sidewall
_WALL_Z1 = 3.55                # end of the sidewall = nose-cone base
_TAN_WALL = math.tan(math.radians(SIDEWALL_ANGLE_DEG))
_R_TOP = _R_MAX - (_WALL_Z1 - _WALL_Z0) * _TAN_WALL     # 1.196 m
_NOSE_H = CAPSULE_HEIGHT_M - _WALL_Z1                    # 0.85 m
_NOSE_OPEN_DEG = 105.0
_POD_T0, _POD_T1 = 0.12, 0.03    # SuperDraco fairing bulge at its bottom / top
_TRUNK_R = TRUNK_DIAMETER_M / 2.0
_TRUNK_Z1 = _HS_SPHERE_R - math.sqrt(_HS_SPHERE_R**2 - _TRUNK_R**2)   # meets the heat shield
_TRUNK_Z0 = CAPSULE_HEIGHT_M - HEIGHT_CLOSED_M                      # -3.7 m

# --- masses [kg] -------------------------------------------------------------------------
_CAPSULE_DRY_KG = 7700.0       # [2]
_PROPELLANT_KG = 2562.0        # [2], carried in tanks in the capsule's lower bay
_TRUNK_KG = 2000.0             # estimate (brief 1.5-2 t; [2] implies <= 2,238 kg)
_M_HEAT_SHIELD = 800.0
_M_NOSE_CONE = 150.0
_M_DOCKING = 300.0
_M_POD = 120.0                 # per SuperDraco pod fairing + structure
_M_SUPERDRACO_PAIR = 60.0      # per pair of engines
_M_DRACO_SET = 40.0            # all Draco nozzles + ports
_M_HATCH = 60.0
_M_CAPSULE_BODY = (_CAPSULE_DRY_KG - _M_HEAT_SHIELD - _M_NOSE_CONE - _M_DOCKING
                   - 4 * (_M_POD + _M_SUPERDRACO_PAIR) - _M_DRACO_SET - _M_HATCH
                   + _PROPELLANT_KG)
_M_SOLAR_EACH = 100.0
_M_RADIATOR_EACH = 100.0
_M_FIN = 37.5
_M_TRUNK_SHELL = _TRUNK_KG - 2 * _M_SOLAR_EACH - 2 * _M_RADIATOR_EACH - 4 * _M_FIN


# ========================================================================================
# geometry helpers (build frame)
# ========================================================================================

def _solid(vertices, faces) -> trimesh.Trimesh:
    """A closed mesh with outward winding, degenerate and duplicate faces removed."""
    mesh = trimesh.Trimesh(vertices=np.asarray(vertices, float), faces=np.asarray(faces),
                           process=True)
    mesh.update_faces(mesh.nondegenerate_faces(height=1e-9))
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    trimesh.repair.fix_normals(mesh)
    if mesh.is_volume and mesh.volume < 0:
        mesh.invert()
    return mesh


def _revolve(profile, sections=_SECTIONS) -> trimesh.Trimesh:
    """Solid of revolution about Z of an (r, z) profile that starts and ends on the axis."""
    mesh = trimesh.creation.revolve(np.asarray(profile, float), sections=sections)
    return _solid(mesh.vertices, mesh.faces)


def _grid_solid(outer, inner) -> trimesh.Trimesh:
    """Closed slab between two (nu, nv, 3) vertex grids of the same shape."""
    nu, nv, _ = outer.shape
    verts = np.concatenate([outer.reshape(-1, 3), inner.reshape(-1, 3)])
    off = nu * nv

    def idx(i, j, layer):
        return layer * off + i * nv + j

    faces = []
    for i in range(nu - 1):
        for j in range(nv - 1):
            a, b, c, d = idx(i, j, 0), idx(i + 1, j, 0), idx(i + 1, j + 1, 0), idx(i, j + 1, 0)
            faces += [[a, b, c], [a, c, d]]
            a, b, c, d = idx(i, j, 1), idx(i + 1, j, 1), idx(i + 1, j + 1, 1), idx(i, j + 1, 1)
            faces += [[a, c, b], [a, d, c]]
    # four side walls
    for i in range(nu - 1):
        for j in (0, nv - 1):
            a, b = idx(i, j, 0), idx(i + 1, j, 0)
            c, d = idx(i + 1, j, 1), idx(i, j, 1)
            faces += [[a, b, c], [a, c, d]]
    for j in range(nv - 1):
        for i in (0, nu - 1):
            a, b = idx(i, j, 0), idx(i, j + 1, 0)
            c, d = idx(i, j + 1, 1), idx(i, j, 1)
            faces += [[a, b, c], [a, c, d]]
    return _solid(verts, faces)


def _wall_radius(z):
    """Radius of the capsule's conical sidewall at height z [m]."""
    return _R_MAX - (np.asarray(z, float) - _WALL_Z0) * _TAN_WALL


def _patch(r_of_z, az0, az1, z0, z1, t0, t1=None, n_az=8, n_z=1, sink=0.005):
    """Conformal slab on a surface of revolution r(z): azimuth [az0, az1] (rad), z in [z0, z1].

    Thickness grows linearly from ``t0`` at ``z0`` to ``t1`` at ``z1`` (radially, above the
    surface); the inner face sits ``sink`` below the surface so the patch is seated on it.
    """
    t1 = t0 if t1 is None else t1
    az = np.linspace(az0, az1, n_az + 1)
    zz = np.linspace(z0, z1, n_z + 1)
    thick = np.linspace(t0, t1, n_z + 1)
    r = np.asarray(r_of_z(zz), float) * np.ones_like(zz)
    ca, sa = np.cos(az), np.sin(az)

    def grid(rr):
        return np.stack([rr[None, :] * ca[:, None], rr[None, :] * sa[:, None],
                         np.broadcast_to(zz, (len(az), len(zz)))], axis=-1)

    return _grid_solid(grid(r + thick), grid(r - sink))


def _prism(poly_uv, thickness, origin, e_u, e_v) -> trimesh.Trimesh:
    """Extrude a convex CCW polygon given in (u, v) by ``thickness`` along e_u x e_v (centred)."""
    poly = np.asarray(poly_uv, float)
    e_u, e_v = np.asarray(e_u, float), np.asarray(e_v, float)
    e_w = np.cross(e_u, e_v)
    base = np.asarray(origin, float) + poly[:, :1] * e_u + poly[:, 1:] * e_v
    top = base + 0.5 * thickness * e_w
    bot = base - 0.5 * thickness * e_w
    n = len(poly)
    verts = np.concatenate([top, bot])
    faces = [[0, i, i + 1] for i in range(1, n - 1)]
    faces += [[n, n + i + 1, n + i] for i in range(1, n - 1)]
    for i in range(n):
        j = (i + 1) % n
        faces += [[i, n + i, n + j], [i, n + j, j]]
    return _solid(verts, faces)


def _cone_along(apex, direction, radius, length, sections=16) -> trimesh.Trimesh:
    """Solid cone with its apex at ``apex`` opening along ``direction`` (a nozzle bell)."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    cone = trimesh.creation.cone(radius=radius, height=length, sections=sections)
    # trimesh's cone: base disc at z = 0, apex at z = +length; flip so the apex is at 0
    flip = trimesh.transformations.rotation_matrix(math.pi, [1.0, 0.0, 0.0], [0, 0, length / 2])
    cone.apply_transform(flip)                       # apex now at z = 0, base at z = +length
    cone.apply_transform(trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d))
    cone.apply_translation(apex)
    return cone


def _wall_frame(az, z):
    """Point on the sidewall at (az, z) and unit vectors: radial, azimuthal, up-slope, normal."""
    e_r = np.array([math.cos(az), math.sin(az), 0.0])
    e_az = np.array([-math.sin(az), math.cos(az), 0.0])
    e_z = np.array([0.0, 0.0, 1.0])
    c, s = math.cos(math.radians(SIDEWALL_ANGLE_DEG)), math.sin(math.radians(SIDEWALL_ANGLE_DEG))
    up = -s * e_r + c * e_z
    normal = c * e_r + s * e_z
    point = float(_wall_radius(z)) * e_r + z * e_z
    return point, e_r, e_az, up, normal


def _concat(meshes) -> trimesh.Trimesh:
    mesh = trimesh.util.concatenate(meshes)
    return _solid(mesh.vertices, mesh.faces) if mesh.is_watertight else mesh


# ========================================================================================
# parts
# ========================================================================================

def _heat_shield():
    ang = np.linspace(0.0, math.asin(_HS_RIM_R / _HS_SPHERE_R), 14)
    arc = np.column_stack([_HS_SPHERE_R * np.sin(ang), _HS_SPHERE_R * (1 - np.cos(ang))])
    profile = np.vstack([arc, [[_HS_EDGE_R, arc[-1, 1] + 0.008], [_HS_EDGE_R, _HS_TOP_Z],
                               [0.0, _HS_TOP_Z]]])
    return _revolve(profile)


def _capsule_body():
    wall = np.column_stack([_wall_radius(np.linspace(_WALL_Z0, _WALL_Z1, 7)),
                            np.linspace(_WALL_Z0, _WALL_Z1, 7)])
    profile = np.vstack([
        [[0.0, _HS_TOP_Z], [_HS_EDGE_R, _HS_TOP_Z], [1.988, 0.46], [_R_MAX, 0.50]],
        wall,
        [[1.17, 3.60], [1.10, 3.64], [0.90, 3.675], [0.60, 3.695], [0.0, 3.70]],
    ])
    return _revolve(profile)


def _nose_cone():
    """Nose-cone shell (4 cm thick) in its closed position: base at z = _WALL_Z1."""
    t = np.linspace(0.0, 1.0, 16)
    n = 2.3                                               # superellipse exponent
    r_out = _R_TOP * np.cos(t * math.pi / 2) ** (2 / n)
    z_out = _WALL_Z1 + _NOSE_H * np.sin(t * math.pi / 2) ** (2 / n)
    th = 0.04
    r_in = (_R_TOP - th) * np.cos(t * math.pi / 2) ** (2 / n)
    z_in = _WALL_Z1 + (_NOSE_H - th) * np.sin(t * math.pi / 2) ** (2 / n)
    # closed loop in (r, z): up the outer surface to the tip, back down the inner surface
    outer = np.column_stack([r_out, z_out])
    inner = np.column_stack([r_in, z_in])
    profile = np.vstack([outer, inner[::-1], outer[:1]])
    mesh = trimesh.creation.revolve(profile, sections=_SECTIONS)
    return _solid(mesh.vertices, mesh.faces)


def _nose_open_transform():
    hinge = [_R_TOP + 0.03, 0.0, _WALL_Z1]
    return trimesh.transformations.rotation_matrix(math.radians(_NOSE_OPEN_DEG), [0, 1, 0], hinge)


def _nose_hinge():
    """Hinge fitting between the capsule top rim and the open nose cone (on the +X side)."""
    z = _WALL_Z1 - 0.02
    a = trimesh.creation.box(extents=[0.16, 0.30, 0.16])
    a.apply_translation([_R_TOP - 0.02, 0.0, z])
    return a


def _docking_adapter():
    collar = trimesh.creation.cylinder(radius=0.70, height=0.32, sections=48)
    collar.apply_translation([0, 0, 3.66 + 0.16])
    ring = trimesh.creation.annulus(r_min=0.52, r_max=0.76, height=0.07, sections=48)
    ring.apply_translation([0, 0, 3.98 + 0.035])
    petals = []
    for k in range(3):
        az = math.radians(30 + 120 * k)
        e_r = np.array([math.cos(az), math.sin(az), 0.0])
        e_t = np.array([-math.sin(az), math.cos(az), 0.0])
        tilt = math.radians(25)                      # leaning in towards the axis
        up = math.cos(tilt) * np.array([0, 0, 1.0]) - math.sin(tilt) * e_r
        poly = [(-0.17, 0.0), (0.17, 0.0), (0.06, 0.30), (-0.06, 0.30)]
        origin = 0.64 * e_r + np.array([0, 0, 4.05])
        petals.append(_prism(poly, 0.03, origin, e_t, up))
    return collar, ring, _concat(petals)


def _forward_dracos():
    nozzles = []
    for k in range(4):
        az = math.radians(45 + 90 * k)
        base = np.array([0.95 * math.cos(az), 0.95 * math.sin(az), 3.67])
        nozzles.append(_cone_along(base - [0, 0, 0.03], [0, 0, 1], 0.06, 0.13, sections=12))
    return nozzles


def _side_draco_cluster(az):
    """Dark port plate on the upper sidewall with three Draco nozzles."""
    z0, z1 = 3.00, 3.36
    half = 0.19 / float(_wall_radius(0.5 * (z0 + z1)))
    plate = _patch(_wall_radius, az - half, az + half, z0, z1, 0.025, n_az=4)
    zc = 0.5 * (z0 + z1)
    p, e_r, e_az, up, n = _wall_frame(az, zc)
    p = p + 0.02 * n
    nozzles = [
        _cone_along(p - 0.03 * n, n, 0.045, 0.10, sections=12),                    # radial
        _cone_along(p - 0.03 * n + 0.12 * e_az, e_az + 0.4 * n, 0.035, 0.09, 12),  # tangential
        _cone_along(p - 0.03 * n - 0.12 * e_az, -e_az + 0.4 * n, 0.035, 0.09, 12),
    ]
    return plate, nozzles


def _superdraco_pod(az):
    """Fairing on the lower sidewall (thickest at the bottom) and its two canted engines."""
    z0, z1 = 0.62, 1.82
    half = 0.33 / float(_wall_radius(0.5 * (z0 + z1)))
    pod = _patch(_wall_radius, az - half, az + half, z0, z1, _POD_T0, _POD_T1, n_az=6, n_z=4)
    p, e_r, e_az, up, n = _wall_frame(az, z0)
    cant = math.radians(12.0)
    down = -math.cos(cant) * up + math.sin(cant) * n
    nozzles = []
    for side in (-1.0, 1.0):
        apex = p + 0.06 * n + side * 0.15 * e_az + 0.16 * up
        nozzles.append(_cone_along(apex, down, 0.10, 0.34, sections=20))
    # dark recess above the nozzle exits (engine bay opening)
    slot_half = 0.27 / float(_wall_radius(z0 + 0.05))

    def pod_surface(z):
        return _wall_radius(z) + 0.005 + _POD_T0 - (_POD_T0 - _POD_T1) * (z - z0) / (z1 - z0)

    slot = _patch(pod_surface, az - slot_half, az + slot_half, z0, z0 + 0.22, 0.01,
                  n_az=4, sink=0.0)
    return pod, nozzles, slot


def _windows_and_hatch():
    windows = []
    for az_deg in (65.0, 115.0, 245.0, 295.0):
        az = math.radians(az_deg)
        z0, z1 = 2.35, 2.80
        half = 0.17 / float(_wall_radius(0.5 * (z0 + z1)))
        windows.append(_patch(_wall_radius, az - half, az + half, z0, z1, 0.035, n_az=3))
    # hatch window (on the hatch, which is 2 cm proud of the wall)
    z0, z1 = 2.05, 2.40
    half = 0.15 / float(_wall_radius(0.5 * (z0 + z1)))
    windows.append(_patch(lambda z: _wall_radius(z) + 0.02, -half, half, z0, z1, 0.02, n_az=3))
    hz0, hz1 = 1.25, 2.60
    hhalf = 0.50 / float(_wall_radius(0.5 * (hz0 + hz1)))
    hatch = _patch(_wall_radius, -hhalf, hhalf, hz0, hz1, 0.025, n_az=10)
    return _concat(windows), hatch


def _trunk_parts():
    trunk = trimesh.creation.annulus(r_min=_TRUNK_R - 0.03, r_max=_TRUNK_R,
                                     height=_TRUNK_Z1 - _TRUNK_Z0, sections=_SECTIONS)
    trunk.apply_translation([0, 0, 0.5 * (_TRUNK_Z0 + _TRUNK_Z1)])
    trunk = _solid(trunk.vertices, trunk.faces)
    z0, z1 = _TRUNK_Z0 + 0.15, _TRUNK_Z1 - 0.22
    gap = math.radians(1.6)

    def r_trunk(z):
        return np.full_like(np.asarray(z, float), _TRUNK_R)

    d = math.radians
    # solar cells on the -X (non-hatch) half, split by the fin at az = 180 deg
    solar_a = _patch(r_trunk, d(90) + gap, d(180) - gap, z0, z1, 0.025, n_az=16)
    solar_b = _patch(r_trunk, d(180) + gap, d(270) - gap, z0, z1, 0.025, n_az=16)
    # radiators on the +X (hatch) half, split by the fin at az = 0
    rad_a = _patch(r_trunk, d(-90) + gap, d(0) - gap, z0, z1, 0.018, n_az=16)
    rad_b = _patch(r_trunk, d(0) + gap, d(90) - gap, z0, z1, 0.018, n_az=16)
    fins = []
    root, span, tip = 1.40, 0.55, 0.55
    # (radial, axial), CCW; the root sinks 2 cm into the trunk wall, and starts 1 mm above the
    # trunk's aft rim, so that the fin's aft face does not overlap the rim in one plane (a tie
    # between the two parts for the rays that hit it)
    poly = [(-0.02, 0.001), (span, 0.001), (span, tip), (-0.02, root)]
    for k in range(4):
        az = d(90 * k)
        e_r = np.array([math.cos(az), math.sin(az), 0.0])
        origin = _TRUNK_R * e_r + np.array([0, 0, _TRUNK_Z0])
        fins.append(_prism(poly, 0.06, origin, e_r, [0, 0, 1.0]))
    return trunk, (solar_a, solar_b), (rad_a, rad_b), fins


# ========================================================================================

def _to_body():
    """Build frame (axis Z, hatch +X) -> body frame (axis +x, hatch +z, y = -Y)."""
    m = np.eye(4)
    m[:3, :3] = np.array([[0.0, 0.0, 1.0],
                          [0.0, -1.0, 0.0],
                          [1.0, 0.0, 0.0]])
    return m


def build() -> TargetModel:
    """Build Crew Dragon with its trunk, nose cone open (see the module docstring)."""
    parts = []   # (name, mesh, material, semantic, mass)

    parts.append(("capsule", _capsule_body(), "white_paint", "module", _M_CAPSULE_BODY))
    parts.append(("heat_shield", _heat_shield(), "heat_shield", "heat_shield", _M_HEAT_SHIELD))
    nose = _nose_cone()
    nose.apply_transform(_nose_open_transform())
    parts.append(("nose_cone", nose, "white_paint", "other", _M_NOSE_CONE))
    parts.append(("nose_cone_hinge", _nose_hinge(), "aluminium", "other", 0.0))
    collar, ring, petals = _docking_adapter()
    parts.append(("docking_adapter", collar, "aluminium", "docking_port", 0.7 * _M_DOCKING))
    parts.append(("docking_capture_ring", ring, "aluminium", "docking_port", 0.2 * _M_DOCKING))
    parts.append(("docking_guide_petals", petals, "aluminium", "docking_port", 0.1 * _M_DOCKING))
    parts.append(("draco_forward", _concat(_forward_dracos()), "titanium", "thruster",
                  0.2 * _M_DRACO_SET))

    ports, nozzles = [], []
    for k in range(4):
        plate, noz = _side_draco_cluster(math.radians(90 * k))
        ports.append(plate)
        nozzles += noz
    parts.append(("draco_ports", _concat(ports), "black_paint", "thruster", 0.0))
    parts.append(("draco_side_nozzles", _concat(nozzles), "titanium", "thruster",
                  0.8 * _M_DRACO_SET))

    for k in range(4):
        pod, noz, slot = _superdraco_pod(math.radians(45 + 90 * k))
        parts.append((f"superdraco_pod_{k + 1}", pod, "white_paint", "engine", _M_POD))
        parts.append((f"superdraco_bay_{k + 1}", slot, "black_paint", "engine", 0.0))
        parts.append((f"superdraco_nozzles_{k + 1}", _concat(noz), "titanium", "engine",
                      _M_SUPERDRACO_PAIR))

    windows, hatch = _windows_and_hatch()
    parts.append(("side_hatch", hatch, "white_paint", "other", _M_HATCH))
    parts.append(("windows", windows, "black_paint", "other", 0.0))

    trunk, solars, rads, fins = _trunk_parts()
    parts.append(("trunk", trunk, "white_paint", "module", _M_TRUNK_SHELL))
    for i, m in enumerate(solars):
        parts.append((f"trunk_solar_cells_{i + 1}", m, "solar_cell", "solar_panel", _M_SOLAR_EACH))
    for i, m in enumerate(rads):
        parts.append((f"trunk_radiator_{i + 1}", m, "white_paint", "radiator", _M_RADIATOR_EACH))
    for i, m in enumerate(fins):
        parts.append((f"trunk_fin_{i + 1}", m, "white_paint", "other", _M_FIN))

    to_body = _to_body()
    comps = []
    for name, mesh, material, semantic, mass in parts:
        mesh = mesh.copy()
        mesh.apply_transform(to_body)
        comps.append(Component(name=name, mesh=mesh, material=material, semantic=semantic,
                               mass_kg=float(mass)))
    return TargetModel(
        name="spacedragon",
        components=centre_on_mass(comps),
        description=("SpaceX Crew Dragon (Dragon 2) with trunk, nose cone open: 8.1 m x 4.0 m "
                     "(SpaceX Dragon page; Wikipedia 'SpaceX Dragon 2'; CRS-6 press kit)"),
        metadata={"axis_convention": "+x docking axis (trunk to nose), +z side hatch, "
                                     "solar cells on -z"},
    )
