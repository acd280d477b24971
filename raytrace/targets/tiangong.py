"""Tiangong space station in its three-module "T" configuration (November 2022 onwards).

The Tianhe core module forms the stem of the T; the Wentian (starboard) and Mengtian (port)
laboratory modules are berthed to the lateral ports of Tianhe's spherical docking hub and form
the crossbar. Each laboratory module carries a pair of very large flexible solar wings at its
far (resource-section) end, ~55 m tip to tip, which dominate the silhouette; Tianhe keeps its
own, smaller pair of flexible wings on its aft resource section. Visiting vehicles (Shenzhou,
Tianzhou) are not included.

Body frame (origin at the centre of mass, metres)
-------------------------------------------------
* +x : along Tianhe's long axis, from the aft docking port towards the docking hub (the
  station's forward, velocity direction in its usual attitude).
* +y : towards the port side, i.e. along Mengtian; Wentian points along -y (starboard).
* +z : zenith, the side of the hub's EVA hatch; the hub's nadir docking port points along -z.

The model is in the "reference" array attitude: every solar wing extends perpendicular to the
module that carries it and lies in the plane of the T (lab wings along +-x, Tianhe's wings
along +-y) with its cell side facing +z, so a view from +z shows the T face-on together with
all six wings — the familiar picture of the complete station.

Key dimensions and sources
--------------------------
============================  =====================================  ==========================
Part                          Dimension used                         Source
============================  =====================================  ==========================
Tianhe core module            16.6 m long (fwd port to aft port),    [1], [2], [3]
                              max. diameter 4.2 m, 22.5 t at launch
Tianhe sections               node + small cylinder (Ø 2.8 m) +      [2], [3], [4]
                              large cylinder (Ø 4.2 m) + aft
                              passage with docking port
Docking hub (node)            sphere Ø 2.8 m; axial (fwd) + radial   brief; [4], [5]
                              (nadir) docking ports, two lateral
                              berthing ports, zenith EVA hatch
Tianhe solar wings            2 wings, 11 m long x 4.6 m wide        [6]
                              (half the area of one lab pair)        [7]
Wentian / Mengtian            17.9 m long, max. Ø 4.2 m, ~23 t       [8], [9], [10]
Wentian sections              work cabin, airlock cabin, resource    [8], [9]
                              cabin
Mengtian sections             work cabin, cargo airlock, payload     [10], [11]
                              cabin ("nested" belly), resource cabin
Lab solar wings               span > 55 m tip to tip, each wing      [7], [12]
                              ~110 m^2 (24.3 m x 2 x 2.25 m here)
Chinarm (Tianhe)              ~10 m robotic arm (stowed, folded)     [13]
Wentian small arm             ~5 m                                   [14]
T configuration               Tianhe centre, labs on both sides;     [15], [16]
                              Wentian starboard, Mengtian port
============================  =====================================  ==========================

[1] Xinhua via teleSUR, 2021-04-29, "China Launches Space Station Core Module Tianhe"
    (16.6 m, max Ø 4.2 m, 22.5 t).
[2] CCTV via news.gscn.com.cn, 2021-04-30 (node + small cylinder + large cylinder).
[3] bnn6.com/view-118431-2.html (Xinhua bilingual: 16.6 m, 4.2 m, 22.5 t; three sections).
[4] ahfyzs.com 2021-04-30 (hub: one axial + one radial docking port, two radial berthing
    ports; EVA hatch at the zenith; aft passage docking port behind the large cylinder);
    haimabooks.com (large cylinder Ø 4.2 m, small cylinder Ø 2.8 m).
[5] Wikipedia "Tianhe core module" (docking hub, Chinarm, two steerable arrays).
[6] defence.pk thread "Chinese Space Station: Core module Tianhe" (two 11 m x 4.6 m arrays).
[7] macaubusiness.com / CMSA, 2022-08: Wentian wingspan > 55 m, one wing ~110 m^2, the pair
    twice the area of Tianhe's wings.
[8] Xinhua (english.news.cn 2022-07-25): Wentian 17.9 m, max Ø 4.2 m, 23 t; work cabin,
    airlock cabin, resource cabin.
[9] pandaily.com "China Successfully Launches Wentian Lab Module" (17.9 m, 23 t, > 55 m).
[10] China Daily 2022-12-26 year-ender: Mengtian ~17.9 m, Ø 4.2 m, > 23 t, four sections.
[11] lqcrsxx.cn "Deciphering the Mengtian experimental cabin" (17.88 m, 4.2 m, 23 t; work
     cabin at the front, payload cabin and cargo airlock nested around it, resource cabin).
[12] scimyst.com / Space.com 2022-08: each Wentian wing ~30 m long, ~110 m^2, span > 55 m.
[13] wionews.com 2023-11-29 (10 m robotic arm).
[14] Wikipedia "Laboratory Cabin Module" (Wentian's 5 m small arm).
[15] english.www.gov.cn 2022-04-18 and China Daily 2022-09-08 (T shape, core in the centre).
[16] graphsearch.epfl.ch "Wentian module" (Wentian relocated to the starboard port);
     Mengtian infobox (berthed to Tianhe's port-side port).

Masses are the published launch masses (22.5 t, 23 t, 23 t) split across the parts of each
module by estimate (resource sections with propellant are the heaviest parts).
"""

from __future__ import annotations

import numpy as np
import trimesh

from ..model import Component, TargetModel, centre_on_mass

__all__ = ["build"]

# --- published dimensions [m] -------------------------------------------------------------
NODE_RADIUS = 1.40               # docking hub sphere, Ø 2.8 m
SMALL_RADIUS = 1.40              # Tianhe small cylinder / lab front sections, Ø 2.8 m
LARGE_RADIUS = 2.10              # max. diameter 4.2 m
TIANHE_FWD_X = 2.10              # forward docking-ring face (node centre at x = 0)
TIANHE_LENGTH = 16.6
LAB_START = 1.80                 # lab docking face distance from the node centre
LAB_LENGTH = 17.9
TIANHE_WING_LENGTH = 11.0
TIANHE_WING_STRIP = 2.15         # two strips + 0.30 m mast gap = 4.6 m wide
LAB_WING_LENGTH = 24.3
LAB_WING_STRIP = 2.25            # 2 x 2.25 x 24.3 = 109 m^2 per wing
WING_GAP = 0.30
WING_THICKNESS = 0.03
LAB_WING_TIP = 27.5              # from the lab axis: 55 m tip to tip

BIG = 64                         # sections for large bodies of revolution
MID = 32
ROD = 16


def _frame(axis, ref, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 transform taking local (x, y, z) to (ref, axis x ref, axis) at ``origin``."""
    e3 = np.asarray(axis, float) / np.linalg.norm(axis)
    e1 = np.asarray(ref, float) - np.dot(ref, e3) * e3
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(e3, e1)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = e1, e2, e3, origin
    return m


def _revolve(profile, transform, sections=BIG) -> trimesh.Trimesh:
    """Closed body of revolution from an (r, s) profile that starts and ends on the axis."""
    mesh = trimesh.creation.revolve(np.asarray(profile, float), sections=sections)
    mesh.apply_transform(transform)
    return mesh


def _rod(p0, p1, radius, sections=ROD) -> trimesh.Trimesh:
    return trimesh.creation.cylinder(radius=radius, segment=np.array([p0, p1], float),
                                     sections=sections)


def _box(extents, centre) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents,
                                transform=trimesh.transformations.translation_matrix(centre))


def _shell_panel(r_in, r_out, theta0, theta1, s0, s1, transform, n=12) -> trimesh.Trimesh:
    """Closed curved panel: an annular sector between angles theta0..theta1, along s0..s1."""
    th = np.linspace(theta0, theta1, n + 1)
    verts = []
    for r in (r_in, r_out):
        for s in (s0, s1):
            verts.append(np.column_stack([r * np.cos(th), r * np.sin(th), np.full_like(th, s)]))
    v = np.vstack(verts)                      # blocks: (in,s0) (in,s1) (out,s0) (out,s1)
    k = n + 1
    i0, i1, o0, o1 = 0, k, 2 * k, 3 * k
    faces = []
    for j in range(n):
        a, b = j, j + 1
        faces += [[o0 + a, o0 + b, o1 + b], [o0 + a, o1 + b, o1 + a]]      # outer
        faces += [[i0 + a, i1 + b, i0 + b], [i0 + a, i1 + a, i1 + b]]      # inner
        faces += [[i0 + a, i0 + b, o0 + b], [i0 + a, o0 + b, o0 + a]]      # s0 end
        faces += [[i1 + a, o1 + b, i1 + b], [i1 + a, o1 + a, o1 + b]]      # s1 end
    for j, sgn in ((0, 1), (n, -1)):                                        # side caps
        quad = [i0 + j, o0 + j, o1 + j, i1 + j]
        if sgn > 0:
            faces += [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
        else:
            faces += [[quad[0], quad[2], quad[1]], [quad[0], quad[3], quad[2]]]
    mesh = trimesh.Trimesh(v, np.array(faces), process=True)
    if mesh.volume < 0:
        mesh.invert()
    mesh.apply_transform(transform)
    return mesh


def _cat(*meshes) -> trimesh.Trimesh:
    return trimesh.util.concatenate(list(meshes))


def _wing(root, along, across, hull_r, length, strip, tip):
    """One flexible wing: (blankets, mast structure).

    ``root`` is the point on the module axis where the wing drive sits, ``along`` the
    direction the wing extends, ``across`` the blanket width direction; the blanket normal
    is ``along x across`` (+-z for every wing here). Two cell strips of width ``strip``
    flank a central mast; ``tip`` is the blanket tip distance from the module axis [m].
    """
    root = np.asarray(root, float)
    d = np.asarray(along, float)
    w = np.asarray(across, float)
    n = np.cross(d, w)
    base = tip - length                                   # blanket root distance from axis
    blankets = []
    for side in (-1.0, 1.0):
        off = side * (WING_GAP / 2 + strip / 2)
        centre = root + d * (base + length / 2) + w * off
        ext = np.abs(d) * length + np.abs(w) * strip + np.abs(n) * WING_THICKNESS
        blankets.append(_box(ext, centre))
    # mast structure: drive at the hull, yoke boom, root and tip spreader bars, central mast
    width = 2 * strip + WING_GAP
    drive = _rod(root + d * (hull_r - 0.05), root + d * (hull_r + 0.30), 0.32, MID)
    yoke = _rod(root + d * (hull_r + 0.30), root + d * (base - 0.06), 0.10)
    bar_ext = np.abs(d) * 0.12 + np.abs(w) * width + np.abs(n) * 0.10
    root_bar = _box(bar_ext, root + d * (base - 0.06))
    tip_bar = _box(bar_ext, root + d * (tip + 0.06))
    mast_ext = np.abs(d) * length + np.abs(w) * 0.16 + np.abs(n) * 0.16
    mast = _box(mast_ext, root + d * (base + length / 2))
    return _cat(*blankets), _cat(drive, yoke, root_bar, tip_bar, mast)


def _port(centre, direction, r_neck, r_ring, s0, s1, s2) -> trimesh.Trimesh:
    """Docking port along ``direction`` from ``centre``: neck s0..s1, ring s1..s2."""
    c = np.asarray(centre, float)
    d = np.asarray(direction, float)
    return _cat(_rod(c + d * s0, c + d * s1, r_neck, MID), _rod(c + d * s1, c + d * s2, r_ring, 48))


def _tianhe():
    X, Y, Z = np.eye(3)
    ax = _frame(X, Y)                                    # local z = +x, local x = +y
    aft_x = TIANHE_FWD_X - TIANHE_LENGTH                 # -14.5
    parts = []

    def add(name, mesh, material, semantic, mass):
        parts.append(Component(name, mesh, material, semantic, mass))

    add("tianhe_node", trimesh.creation.icosphere(subdivisions=3, radius=NODE_RADIUS),
        "silver_mli", "module", 1900.0)
    add("tianhe_forward_port", _port((0, 0, 0), X, 0.55, 0.75, 1.25, 1.85, TIANHE_FWD_X),
        "aluminium", "docking_port", 120.0)
    add("tianhe_nadir_port", _port((0, 0, 0), -Z, 0.55, 0.75, 1.25, 1.85, 2.10),
        "aluminium", "docking_port", 120.0)
    add("tianhe_zenith_hatch", _port((0, 0, 0), Z, 0.60, 0.55, 1.25, 1.62, 1.70),
        "aluminium", "docking_port", 80.0)
    add("tianhe_berthing_ports", _cat(_rod((0, 1.25, 0), (0, LAB_START, 0), 0.60, MID),
                                      _rod((0, -1.25, 0), (0, -LAB_START, 0), 0.60, MID)),
        "aluminium", "docking_port", 160.0)
    # pressurised cabin: small cylinder (living quarters) then cone + large cylinder
    add("tianhe_small_cylinder",
        _revolve([(0, -4.6), (SMALL_RADIUS, -4.6), (SMALL_RADIUS, -1.05), (0, -1.05)], ax),
        "silver_mli", "module", 4000.0)
    add("tianhe_large_cylinder",
        _revolve([(0, -11.0), (LARGE_RADIUS, -11.0), (LARGE_RADIUS, -5.6),
                  (SMALL_RADIUS, -4.6), (0, -4.6)], ax),
        "silver_mli", "module", 6600.0)
    add("tianhe_resource_section",
        _revolve([(0, -13.9), (1.60, -13.9), (LARGE_RADIUS, -13.6), (LARGE_RADIUS, -11.0),
                  (0, -11.0)], ax),
        "silver_mli", "bus", 6810.0)
    add("tianhe_aft_port", _port((-13.8, 0, 0), -X, 0.55, 0.75, 0.0, -13.8 - aft_x - 0.15,
                                 -13.8 - aft_x),
        "aluminium", "docking_port", 120.0)
    nozzles = []
    for zc in (-1.15, 1.15):
        cone = trimesh.creation.cone(radius=0.26, height=0.55, sections=MID)
        cone.apply_transform(_frame(X, Y, (-14.40, 0.0, zc)))
        nozzles.append(cone)
    add("tianhe_main_engines", _cat(*nozzles), "titanium", "engine", 250.0)
    add("tianhe_radiators",
        _cat(_shell_panel(LARGE_RADIUS + 0.005, LARGE_RADIUS + 0.045, np.radians(-35),
                          np.radians(35), -10.7, -6.0, ax),
             _shell_panel(LARGE_RADIUS + 0.005, LARGE_RADIUS + 0.045, np.radians(145),
                          np.radians(215), -10.7, -6.0, ax)),
        "white_paint", "radiator", 400.0)
    # Chinarm (~10 m), stowed folded along the top of the large cylinder
    zc = LARGE_RADIUS + 0.05 + 0.18
    arm = _cat(_rod((-10.6, 0.22, zc), (-5.8, 0.22, zc), 0.18),
               _rod((-10.6, -0.22, zc), (-5.8, -0.22, zc), 0.18),
               _box((0.5, 0.9, 0.45), (-10.85, 0.0, zc)),
               _box((0.5, 0.9, 0.45), (-5.55, 0.0, zc)),
               _box((0.8, 0.8, 0.10), (-8.2, 0.0, LARGE_RADIUS + 0.03)))
    add("tianhe_chinarm", arm, "white_paint", "boom", 740.0)
    for side, sgn in (("port", 1.0), ("stbd", -1.0)):
        blankets, mast = _wing((-12.3, 0.0, 0.0), sgn * Y, X, LARGE_RADIUS,
                               TIANHE_WING_LENGTH, TIANHE_WING_STRIP, 3.2 + TIANHE_WING_LENGTH)
        add(f"tianhe_wing_{side}", blankets, "solar_cell", "solar_panel", 300.0)
        add(f"tianhe_wing_{side}_mast", mast, "aluminium", "boom", 300.0)
    return parts


def _lab(name, sgn):
    """Wentian (sgn = -1, starboard) or Mengtian (sgn = +1, port) along sgn * y."""
    X, Y, Z = np.eye(3)
    out = sgn * Y
    ax = _frame(out, X)                                  # local z = outward, local x = +x
    end = LAB_START + LAB_LENGTH                         # 19.7 m from the node centre
    wing_s = 17.6
    parts = []

    def add(part, mesh, material, semantic, mass):
        parts.append(Component(f"{name}_{part}", mesh, material, semantic, mass))

    def p(s, x=0.0, z=0.0):
        return np.array([x, sgn * s, z])

    add("docking_ring", _rod(p(LAB_START), p(2.10), 0.75, 48), "aluminium", "docking_port", 150.0)
    small = _revolve([(0, 2.10), (0.95, 2.10), (SMALL_RADIUS, 2.70), (SMALL_RADIUS, 6.30),
                      (0, 6.30)], ax)
    resource = _revolve([(0, 15.70), (LARGE_RADIUS, 15.70), (LARGE_RADIUS, 19.40),
                         (1.50, end), (0, end)], ax)
    radiators = _cat(
        _shell_panel(LARGE_RADIUS + 0.005, LARGE_RADIUS + 0.045, np.radians(-30), np.radians(30),
                     8.0, 12.3, ax),
        _shell_panel(LARGE_RADIUS + 0.005, LARGE_RADIUS + 0.045, np.radians(150), np.radians(210),
                     8.0, 12.3, ax))
    top = LARGE_RADIUS
    if name == "wentian":
        add("work_cabin_small", small, "silver_mli", "module", 3300.0)
        add("work_cabin_large",
            _revolve([(0, 6.30), (SMALL_RADIUS, 6.30), (LARGE_RADIUS, 7.30),
                      (LARGE_RADIUS, 12.80), (0, 12.80)], ax),
            "silver_mli", "module", 5800.0)
        add("airlock_cabin",
            _revolve([(0, 12.80), (LARGE_RADIUS, 12.80), (LARGE_RADIUS, 15.70), (0, 15.70)], ax),
            "silver_mli", "module", 2600.0)
        add("eva_hatch", _rod(p(14.25, z=top - 0.30), p(14.25, z=top + 0.18), 0.62, 48),
            "aluminium", "docking_port", 100.0)
        add("resource_section", resource, "silver_mli", "bus", 8250.0)
        zc = top + 0.05 + 0.12
        arm = _cat(_rod(p(7.9, z=zc), p(12.4, z=zc), 0.12),
                   _box((0.5, 0.5, 0.40), p(7.65, z=zc)),
                   _box((0.5, 0.5, 0.40), p(12.65, z=zc)))
        add("small_arm", arm, "white_paint", "boom", 300.0)
    else:
        add("work_cabin", small, "silver_mli", "module", 3300.0)
        add("payload_cabin",
            _revolve([(0, 6.30), (SMALL_RADIUS, 6.30), (LARGE_RADIUS, 7.30),
                      (LARGE_RADIUS, 15.70), (0, 15.70)], ax),
            "silver_mli", "module", 8200.0)
        add("cargo_airlock_hatch", _rod(p(13.6, z=-top + 0.30), p(13.6, z=-top - 0.15), 0.70, 48),
            "aluminium", "docking_port", 150.0)
        # deployed exposed-payload platform on the zenith side, on two pylons
        plat_z = top + 0.42
        platform = _cat(_box((2.6, 3.6, 0.12), p(11.0, z=plat_z)),
                        _box((0.3, 0.3, 0.42), p(9.8, z=top + 0.15)),
                        _box((0.3, 0.3, 0.42), p(12.2, z=top + 0.15)),
                        _box((0.5, 0.5, 0.30), p(10.2, x=0.8, z=plat_z + 0.21)),
                        _box((0.5, 0.5, 0.30), p(11.8, x=-0.8, z=plat_z + 0.21)))
        add("exposed_platform", platform, "aluminium", "instrument", 400.0)
        add("resource_section", resource, "silver_mli", "bus", 8300.0)
    add("radiators", radiators, "white_paint", "radiator", 500.0)
    for side, dx in (("fwd", 1.0), ("aft", -1.0)):
        blankets, mast = _wing(p(wing_s), dx * X, Y, LARGE_RADIUS, LAB_WING_LENGTH,
                               LAB_WING_STRIP, LAB_WING_TIP)
        add(f"wing_{side}", blankets, "solar_cell", "solar_panel", 550.0)
        add(f"wing_{side}_mast", mast, "aluminium", "boom", 450.0)
    return parts


def build() -> TargetModel:
    """Build the Tiangong T-configuration model (body frame, metres, origin at the CoM)."""
    comps = _tianhe() + _lab("wentian", -1.0) + _lab("mengtian", 1.0)
    comps = centre_on_mass(comps)
    return TargetModel(
        name="tiangong",
        components=comps,
        description=("Tiangong space station, T configuration (Tianhe + Wentian + Mengtian, "
                     "2022-): CMSA/Xinhua published lengths, diameters, masses and wing spans"),
        metadata={"published_mass_kg": {"tianhe": 22500.0, "wentian": 23000.0,
                                        "mengtian": 23000.0}},
    )
