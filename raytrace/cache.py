"""Body-space radiance cache: environment occlusion and inter-reflection, precomputed once.

A target is rigid: in its body frame the geometry never changes, only the light does. So the
expensive part of global illumination — which part of the surface sees which other part, and
which directions of the sky it sees — is computed once per target and reused for every frame
(the idea of precomputed radiance transfer, Sloan et al. 2002, doi:10.1145/566654.566612, with
a radiosity-style surface discretisation, Cohen & Wallace 1993).

Samples
    Surface points on a barycentric lattice over every triangle: a triangle whose longest edge
    is ℓ gets s = ⌈ℓ/h⌉ subdivisions ((s+1)(s+2)/2 lattice points, h the spacing). Corner
    points are shared by all triangles that share the (welded) vertex and its shading normal,
    so the cache is continuous across smooth meshes. Each sample has a front row and, on open
    (two-sided) components, a back row.
Transfer (once)
    From every row, G cosine-weighted stratified rays (from a lattice point on a concave
    crease, a few ray offsets inside its triangle: on the crease it lies on the other face's
    plane too, :data:`_ORIGIN_NUDGE`). A ray that hits the front of a surface
    (or either side of an open one) adds 1/G, split over the three lattice points around the
    hit with their interpolation weights, to the row's entries of the surface matrix W_ss; a
    ray that does not escape (it hits a surface, or the inside of a closed shell) adds 1/G to
    the octahedral sky cell (n×n) it would have left through (W_sb: the sky it blocks). A
    row whose rays mostly hit the inside of a closed shell lies buried in another part: it
    takes the values of the nearest unburied row of its component and side.
Per frame
    E_sun (one shadow ray per row), L_env on the sky cells (Earth + ambient), the
    environment's unoccluded irradiance E_env(n) on every row's plane (a table,
    :func:`raytrace.environment.irradiance_table`), then Gauss–Seidel sweeps of the
    radiosity equation for irradiance, all bounces (one thread, rows in order):

        E = E_sun + E_env(n) − π W_sb L_env + W_ss (ρ ⊙ E),     L_out = ρ/π ⊙ E

    where ρ is each surface's bounce albedo (diffuse plus the cosine-averaged specular albedo:
    light reflected towards other parts is treated as diffuse), except on glossy parts (metals
    and MLI foils, whose specular albedo exceeds their diffuse one). There W_ss carries only the
    diffuse part; the specular part follows the lobe: every cache ray that hits a glossy part
    continues along one direction drawn from its GGX lobe (weight f_s·cos/pdf, RGB) into the
    matrices W_g (the surface it reaches, times that surface's ρ E) and W_gb (the sky cell it
    leaves through), and the Sun's specular reflection at the hit towards the row,
    f_s(sun → row)·cosθ_sun·E_sun·V, is added exactly per frame. A gold plate's reflection onto a
    wall was 0.45× or 4.4× the quadrature with the diffuse stand-in, depending on where the glint
    points; it is now within 3 % / 12 % (tests/raytrace/test_glossy_cache.py). Seen along
    a given ray (:func:`raytrace._surface.incoming`), a glossy surface instead returns its
    diffuse part, its exact specular reflection of the Sun towards that ray, and its
    specular albedo times the rest of its irradiance (as if that arrived uniformly).

    The sky term is the complement of what the row's rays block: on an open surface it is
    exact (to the table's ~0.5 %), where summing the escaping rays' cells instead was a
    G-ray, 1-cell quadrature of Earth's disc, its limb and its terminator (the Earth-facing
    side of a sphere 400 km up: 3.6 % low with 128 rays and 16² cells).

Contact rows
    Where two parts touch (a rod on a module), irradiance changes within a fraction of h, and
    merging in cells of h/2 put one sample in the crevice for a whole thin triangle: a rod's
    0.2 m-wide triangles lying on Tiangong's module made a band 30-40 % too bright beside it,
    and a plate beside a rod thinner than h was 74 % too dark (tests/raytrace/test_cache_contact.py).
    A coarse row is near a contact when a quarter of its rays hit a surface nearer than h/4.
    The faces around it get a second lattice, twice as fine, merged in cells of h/8. Its rows
    within h of a contact row cast their own G rays, binned on the coarse lattice, and gather
    once per frame from the solved coarse rows (one Jacobi step: the same sources, their
    value at convergence); the rest of a refined face takes the coarse rows' interpolation.
    Their direct sunlight is always the coarse rows' interpolation: the renderer traces the
    Sun exactly at every pixel, and what it reads from these rows is indirect light.
    Pixels and gather rays read the finer lattice on refined faces, the coarse one elsewhere.
    On the 12 benchmark scenes, median relative RMS error, ``fast`` 6.46 → 5.31 %,
    ``balanced``-8 3.35 → 3.22 %, -16 2.30 → 2.23 %; 1.07–1.28× the coarse rows, the build
    ~3× and the per-frame solve +1–16 ms (BENCHMARKS.md, "Contact rows").

Errors: the cache resolves occlusion to the lattice spacing and blocked sky to one cell; the
``balanced`` renderer therefore uses it only one bounce away from the pixel (final gather),
and ``fast`` uses it directly, interpolated (see :mod:`raytrace.shade`).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
import trimesh
from scipy.spatial import cKDTree

from . import environment as env, presets
from ._cache_kernels import (_bin_hits, _cache_rays, _csr_sum, _gauss_seidel_sweep, _glint_lattice, _glints,
                             _glossy_bounce,
                             _interp_rows, _irradiance_corners, _jacobi_step, _lattice_points, _lookup_rows, _oct_cells,
                             _ray_cells, _rows_irradiance, _sun_rays, _zero_rows)
from ._jit import side_cores
from ._threads import submit
from .brdf import bounce_albedo

__all__ = ["CacheFrame", "RadianceCache"]

_BURIED_FRACTION = 0.25
# contact rows (module notes): a coarse row is near a contact when at least this fraction of its
# rays hit a surface nearer than _CONTACT_DISTANCE lattice spacings; the faces around it get
# _CONTACT_REFINE times the subdivisions, merged in cells of _CONTACT_CELL spacings
_CONTACT_FRACTION = 0.25
_CONTACT_DISTANCE = 0.25
_CONTACT_REFINE = 2
_CONTACT_CELL = 0.125
_CONTACT_REACH = 1.0
# the cache rays (and a row's shadow ray) leave a lattice point on a concave crease (an edge its
# triangle shares with another face of the same part that rises above the triangle's plane on a side
# with rows: RadianceCache._crease_edges) from _ORIGIN_NUDGE ray offsets (Scene.ray_eps_m) inside
# the triangle, away from the edge's line (RadianceCache._ray_origins), besides the offset along the
# normal: such a point lies on the other face's plane too, and its rays towards that face passed
# through it or hit it at t ≈ 0. On an open (single-sheet) L-shaped corner the crease rows read
# 0–89 % of their indirect light and the rows beside them 38–70 %, against the 2-D radiosity of the
# corner; now within 3.7 % (tests/raytrace/test_cache_crease.py). The inner walls of a white open
# box rendered 1–5 % too dark with ``fast`` and ``balanced`` alike (BENCHMARKS.md, "Concave creases
# of open meshes"). Convex edges and contacts with other parts stay as they were: there a point
# moved onto one face reads light it should not (a cylinder's rim flush against another part's face:
# 35 % too bright beside it)
_ORIGIN_NUDGE = 4.0


def _barycentrics(tri, p):
    """Barycentrics (b1, b2) of points ``p`` (n, 3) in the planes of triangles ``tri`` (n, 3, 3),
    by least squares on the edges (p ≈ v0 + b1 (v1 − v0) + b2 (v2 − v0)), and whether the
    triangle has an area (where it has none, b1 and b2 mean nothing)."""
    e1, e2, dp = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], p - tri[:, 0]
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    p1, p2 = (dp * e1).sum(1), (dp * e2).sum(1)
    den = d11 * d22 - d12 * d12
    ok = den > 0.0
    den = np.where(ok, den, 1.0)
    return (d22 * p1 - d12 * p2) / den, (d11 * p2 - d12 * p1) / den, ok


def _EMPTY_CSR3(n_rows):
    """An empty (indptr, indices, data (0, 3)) matrix of ``n_rows`` rows."""
    return np.zeros(n_rows + 1, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))


def _row_ids(key):
    """The inverse of ``np.unique(key, axis=0, return_inverse=True)`` (the index of each row
    of the int64 matrix ``key`` among its distinct rows, sorted lexicographically), from a
    1-d sort: each row packed into one int64 in mixed radix (column minus its minimum, times
    the product of the later columns' ranges), which orders the packed keys as the rows. The
    2-d sort compares rows field by field and took 0.3–0.7 s per lattice of the built-in
    targets; this takes a few ms. Falls back to it where the ranges' product overflows."""
    key = np.asarray(key, dtype=np.int64)
    if len(key) == 0:
        return np.empty(0, np.int64)
    lo = key.min(axis=0)
    span = [int(x) for x in key.max(axis=0) - lo + 1]
    if math.prod(span) >= 1 << 62:
        return np.unique(key, axis=0, return_inverse=True)[1].ravel().astype(np.int64)
    packed = np.zeros(len(key), np.int64)
    for c in range(key.shape[1]):
        packed *= span[c]
        packed += key[:, c] - lo[c]
    return np.unique(packed, return_inverse=True)[1].ravel().astype(np.int64)


def _ranges(starts, counts):
    """The concatenated index ranges [start, start + count) (int64)."""
    counts = np.asarray(counts, np.int64)
    if counts.sum() == 0:
        return np.empty(0, np.int64)
    ends = np.cumsum(counts)
    offs = np.repeat(np.asarray(starts, np.int64) - (ends - counts), counts)
    return np.arange(int(ends[-1]), dtype=np.int64) + offs


def _stack_pieces(pieces, rows, n_rows: int):
    """(indptr, indices, data (nnz, k)) of one CSR matrix of n_rows rows from :func:`_csr_sum`'s
    pieces of consecutive runs of ``rows`` (ascending; the other rows empty), in order."""
    counts = np.zeros(n_rows, np.int64)
    counts[rows] = np.concatenate([np.diff(p[0]) for p in pieces])
    indptr = np.concatenate([[0], np.cumsum(counts)])
    return indptr, np.concatenate([p[1] for p in pieces]), np.concatenate([p[2] for p in pieces])


def _stack_rows(pieces, rows, n_rows: int, n_cols: int):
    """One scipy CSR matrix (n_rows, n_cols), canonical (columns sorted, no duplicates), of one
    channel, from :func:`_csr_sum`'s pieces (:func:`_stack_pieces`)."""
    indptr, indices, data = _stack_pieces(pieces, rows, n_rows)
    W = sp.csr_matrix((np.ascontiguousarray(data[:, 0]), indices, indptr), shape=(n_rows, n_cols))
    W.has_sorted_indices = True
    return W


class CacheFrame:
    """The cache solved for one frame's light.

    Attributes
    ----------
    irradiance_W_m2 : ndarray, shape (rows, 3)
        Total irradiance per row, all bounces [W/m²].
    sun_irradiance_W_m2 : ndarray, shape (rows,)
        Direct sunlight per row (with shadow) [W/m²].
    indirect_W_m2 : ndarray, shape (rows, 3)
        Irradiance from everything but the direct Sun (sky, Earth, other parts) [W/m²].
    radiance_out : ndarray, shape (rows, 3)
        Outgoing radiance, diffuse-equivalent, ρ/π · E [W/(m²·sr)].
    iterations : int
        Gauss–Seidel sweeps taken.
    """

    __slots__ = ("indirect_W_m2", "irradiance_W_m2", "iterations", "radiance_out", "sun_irradiance_W_m2")

    def __init__(self, E, E_sun, radiance_out, iterations, indirect=None):
        self.irradiance_W_m2 = E
        self.sun_irradiance_W_m2 = E_sun
        self.indirect_W_m2 = np.ascontiguousarray(E - E_sun[:, None]) if indirect is None else indirect
        self.radiance_out = radiance_out
        self.iterations = iterations


class RadianceCache:
    """The precomputed transfer of a :class:`~raytrace.scene.Scene` (see module notes).

    Parameters
    ----------
    scene : Scene
    spacing_m : float, optional
        Lattice spacing h (default: 1/60 of the target's bounding-box diagonal) [m].
    rays_per_sample : int
        G, rays per sample row (a multiple of 8) [-].
    sky_cells : int
        n, the octahedral sky map has n×n cells [-].
    """

    def __init__(self, scene, *, spacing_m: float | None = None, rays_per_sample: int = 128, sky_cells: int = 16,
                 contact_refine: bool = True):
        if spacing_m is None:
            spacing_m = scene.scale_m / 60.0
        if not (math.isfinite(spacing_m) and spacing_m > 0):
            raise ValueError(f"spacing_m must be a positive finite length, got {spacing_m!r}")
        if not (isinstance(rays_per_sample, int) and rays_per_sample >= 8 and rays_per_sample % 8 == 0):
            raise ValueError(f"rays_per_sample must be a positive multiple of 8, got {rays_per_sample!r}")
        if not (isinstance(sky_cells, int) and 4 <= sky_cells <= 256):
            raise ValueError(f"sky_cells must be an integer in [4, 256], got {sky_cells!r}")
        if not isinstance(contact_refine, bool):
            raise ValueError(f"contact_refine must be True or False, got {contact_refine!r}")
        self.scene = scene
        self.spacing_m = float(spacing_m)
        self.G = rays_per_sample
        self.n_cells = sky_cells
        self.eps_m = scene.ray_eps_m
        self.two_sided_face = scene.two_sided[scene.component_of_face]
        V, F = scene.vertices, scene.faces
        tri = V[F]
        # s from the longest edge, as documented: the square root of the area left long thin
        # triangles (a module's barrel, a truss rod) one lattice cell across their whole length
        longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
        face_s = np.clip(np.ceil(longest / self.spacing_m), 1, 64).astype(np.int64)
        # merge lattice points of one component that lie in the same cell of side h/2 and whose
        # normals fall in the same octahedral cell (8×8): one sample each, shared by triangles
        lat_start, lat_ids, pos, nrm, sample_face = self._lattice(np.arange(len(F)), face_s, 0.5 * self.spacing_m)
        n_c = len(pos)
        self.n_coarse_rows = 2 * n_c
        valid = self._row_flags(sample_face)
        # the coarse system: its rows, its lattice (the columns of every transfer matrix)
        self._c_face_s, self._c_lat_start, self._c_lat_ids = face_s, lat_start, lat_ids
        self._c_pos, self._c_nrm = pos, nrm
        self._creases = self._crease_edges()
        self._c_ray_pos = self._ray_origins(pos, sample_face)
        comp_c = scene.component_of_face[sample_face]
        mats = scene.materials
        bounce = np.array([bounce_albedo(m.diffuse, m.f0, m.roughness) for m in mats])
        self.bounce_albedo = bounce  # per material (component), RGB
        diffuse = np.array([m.diffuse for m in mats], dtype=np.float64)
        # glossy parts (specular albedo above diffuse: metals, MLI foils): the light they
        # reflect towards other parts follows their lobe (one sampled ray per cache ray that
        # hits them, and the Sun's specular reflection exactly), not a diffuse stand-in
        self.glossy_comp = (bounce - diffuse).max(axis=1) > diffuse.max(axis=1)
        self.f0 = np.array([m.f0 for m in mats], dtype=np.float64)
        self.alpha = np.array([m.roughness for m in mats], dtype=np.float64)
        rho_ss = np.where(self.glossy_comp[:, None], diffuse, bounce)  # per component
        self._c_rho_ss = np.repeat(rho_ss[comp_c], 2, axis=0)
        self._c_rho_bounce = np.repeat(bounce[comp_c], 2, axis=0)
        self._c_comp_rows = np.repeat(comp_c, 2)
        raw = self._cast(self._c_ray_pos, nrm, np.flatnonzero(valid).astype(np.int64), 0)
        ok = self._unburied(valid, raw)
        self._c_alias = self._aliases(pos, nrm, self._c_comp_rows, valid & ~ok, ok)
        self._c_solved = ok
        self._c_unsolved_rows = np.flatnonzero(~ok)
        self._c_valid = valid & (ok | (self._c_alias != np.arange(self.n_coarse_rows)))
        self._c = self._matrices(raw, ok, 0, self.n_coarse_rows)
        # contact rows: the lattice near contacts between parts, refined (see module notes)
        lookup = (face_s, lat_start, lat_ids, pos, nrm, valid, ok, self._c_alias, self._c_comp_rows)
        self.contact_rows = np.empty(0, np.int64)  # rows that gather for themselves
        self._f = None
        if contact_refine:
            contact = np.zeros(self.n_coarse_rows, dtype=bool)
            contact[raw["rows"]] = raw["near"] >= _CONTACT_FRACTION * self.G
            if contact.any():
                lookup = self._refine(contact, *lookup)
        # what the renderer reads: per lookup row (coarse rows, then contact rows)
        face_s, lat_start, lat_ids, pos, nrm, valid, solved, self._alias, row_component = lookup
        self.face_s, self.lat_start, self.lat_ids = face_s, lat_start, lat_ids
        self.positions, self.normals = pos, nrm
        self.n_samples = len(pos)
        self.n_rows = 2 * self.n_samples
        self.rho_bounce = bounce[row_component]
        self._rho_over_pi = self.rho_bounce / math.pi
        self.valid = valid & (solved | (self._alias != np.arange(self.n_rows)))

    def _refine(self, contact, face_s, lat_start, lat_ids, pos, nrm, valid, ok, alias_c, comp_rows_c):
        """The contact rows around the coarse rows flagged in ``contact`` (module notes): builds
        ``self._f`` and returns the lookup lattice and per-row arrays (coarse rows first)."""
        scene = self.scene
        n_c = len(pos)
        pts = contact[2 * lat_ids] | contact[2 * lat_ids + 1]
        fine = np.zeros(len(face_s), dtype=bool)
        fine[np.repeat(np.arange(len(face_s)), (face_s + 1) * (face_s + 2) // 2)[pts]] = True
        ff = np.flatnonzero(fine)
        s_f = np.minimum(_CONTACT_REFINE * face_s[ff], 128)
        _, f_ids, pos_f, nrm_f, face_f = self._lattice(ff, s_f, _CONTACT_CELL * self.spacing_m)
        n_f = len(pos_f)
        valid_f = self._row_flags(face_f)
        # the lookup lattice: the refined one on refined faces, the coarse one elsewhere
        look_s = face_s.copy()
        look_s[ff] = s_f
        counts = (look_s + 1) * (look_s + 2) // 2
        look_start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        look_ids = np.empty(int(counts.sum()), np.int64)
        coarse_faces = np.flatnonzero(~fine)
        c_counts = (face_s + 1) * (face_s + 2) // 2
        look_ids[_ranges(look_start[coarse_faces], counts[coarse_faces])] = \
            lat_ids[_ranges(lat_start[coarse_faces], c_counts[coarse_faces])]
        look_ids[_ranges(look_start[ff], counts[ff])] = n_c + f_ids
        # only the refined samples within _CONTACT_REACH spacings of a contact row cast rays (a
        # refined face can reach far from its contact); they are rows 2n_c… of the joint sample
        # list, so their jitter keys differ from every coarse row's
        near = np.flatnonzero(contact[0::2] | contact[1::2])
        dist, _ = cKDTree(pos[near]).query(pos_f, k=1, distance_upper_bound=_CONTACT_REACH * self.spacing_m)
        active = np.repeat(np.isfinite(dist), 2)
        pos_all, nrm_all = np.concatenate([pos, pos_f]), np.concatenate([nrm, nrm_f])
        self.contact_rows = 2 * n_c + np.flatnonzero(valid_f & active)
        ray_pos_f = self._ray_origins(pos_f, face_f)
        # their W_ss, W_sb and W_g summed by each chunk of rays as it is cast (their columns'
        # aliases are the coarse rows', known by then; presets.ASSEMBLE_CONTACT_PER_CHUNK), not
        # from lists of every hit: the same matrices bit for bit; the cache of a CAD mesh with many
        # contacts built in ~1/3 of the time, in less memory (BENCHMARKS.md, "Building the
        # radiance cache of a user's mesh"). False: from the lists.
        raw_f = self._cast(np.concatenate([self._c_ray_pos, ray_pos_f]), nrm_all, self.contact_rows, 2 * n_c,
                           assemble=(valid_f, 2 * n_c) if presets.ASSEMBLE_CONTACT_PER_CHUNK else None)
        ok_f = self._unburied(valid_f, raw_f, row0=2 * n_c)
        comp_rows = np.concatenate([comp_rows_c, np.repeat(scene.component_of_face[face_f], 2)])
        ok_all = np.concatenate([ok, ok_f])
        alias = self._aliases(pos_all, nrm_all, comp_rows, np.concatenate([np.zeros_like(ok), valid_f & ~ok_f]),
                              ok_all)
        alias[:2 * n_c] = alias_c
        self._f = dict(self._matrices(raw_f, ok_f, 2 * n_c, 2 * n_f), pos=pos_f, ray_pos=ray_pos_f, nrm=nrm_f,
                       solved=ok_f & active,
                       passive=np.flatnonzero(~active))
        # the coarse rows interpolated at every refined sample: the passive samples' light and
        # every refined sample's direct sunlight (as without them)
        b1, b2, _ = _barycentrics(scene.vertices[scene.faces[face_f]], pos_f)
        cols = np.empty((2 * n_f, 3), np.int64)
        w = np.empty((2 * n_f, 3))
        _interp_rows(self._c_valid, face_s, lat_start, lat_ids, face_f, b1, b2, cols, w)
        self._f["P"] = sp.csr_matrix((w.ravel(), (np.repeat(np.arange(2 * n_f), 3), cols.ravel())),
                                     shape=(2 * n_f, 2 * n_c))
        self._f["P_passive"] = self._f["P"][self._f["passive"]]
        self._f["unsolved_rows"] = np.flatnonzero(~self._f["solved"])
        return (look_s, look_start, look_ids, pos_all, nrm_all, np.concatenate([valid, valid_f]), ok_all, alias,
                comp_rows)

    def _crease_edges(self):
        """Two (n_faces, 3) bool arrays: the edge opposite vertex i of a face is a concave crease
        seen from a side of it that has cache rows (another face of the same part shares it,
        vertices welded by position, and rises above the face's plane on that side, the front or
        either side of an open part, by more than 10⁻³ of its reach); and vertex i of a face is
        an end of such an edge of any face (a fan of triangles touches a crease at a vertex
        only)."""
        scene = self.scene
        V = np.asarray(scene.vertices, dtype=np.float64)
        Vw, weld = np.unique(V, axis=0, return_inverse=True)
        F = weld.ravel()[scene.faces]
        comp = scene.component_of_face
        out = np.zeros((len(F), 3), dtype=bool)
        pairs, edges = trimesh.graph.face_adjacency(faces=F, return_edges=True)
        if len(pairs):
            same = comp[pairs[:, 0]] == comp[pairs[:, 1]]
            pairs, edges = pairs[same], edges[same]
            normal = np.asarray(scene.face_normal, dtype=np.float64)
            two = np.asarray(self.two_sided_face, dtype=bool)
            for a, b in ((0, 1), (1, 0)):
                fa, fb = pairs[:, a], pairs[:, b]
                own = (F[fa] != edges[:, :1]) & (F[fa] != edges[:, 1:])  # the vertex of fa off the edge
                other = (F[fb] != edges[:, :1]) & (F[fb] != edges[:, 1:])
                i = own.argmax(axis=1)
                w = F[fb][np.arange(len(fb)), other.argmax(axis=1)]
                reach = Vw[w] - Vw[edges[:, 0]]
                height = (reach * normal[fa]).sum(axis=1)
                tol = 1e-3 * np.linalg.norm(reach, axis=1)
                crease = (height > tol) | (two[fa] & (height < -tol))
                np.logical_or.at(out, (fa[crease], i[crease]), True)
        ends = np.zeros(len(Vw), dtype=bool)
        f, i = np.nonzero(out)
        ends[F[f, (i + 1) % 3]] = True
        ends[F[f, (i + 2) % 3]] = True
        return out, ends[F]

    def _ray_origins(self, pos, face):
        """Where the rays of the samples at ``pos`` (on triangles ``face``) leave from, before
        the offset along the normal: a sample on an edge of its triangle that is a concave
        crease (:meth:`_crease_edges`) moved into the triangle perpendicular to that edge by
        _ORIGIN_NUDGE ray offsets; one at a vertex between two such edges, or at a vertex that
        ends a crease none of its triangle's edges lies on, along the bisector until it is that
        far from both edges' lines (k/sin(α/2) for a vertex angle α); at most a quarter of the
        way to the centroid. The others stay where they are (see :data:`_ORIGIN_NUDGE`)."""
        tri = self.scene.vertices[self.scene.faces[face]].astype(np.float64)
        b1, b2, ok = _barycentrics(tri, pos)
        bary = np.stack([1.0 - b1 - b2, b1, b2], axis=1)
        k = _ORIGIN_NUDGE * self.eps_m
        move = np.zeros_like(pos)
        # inward unit normal (in the triangle's plane) of the edge opposite each vertex
        inward = []
        for i in range(3):
            vi, vj, vk = tri[:, i], tri[:, (i + 1) % 3], tri[:, (i + 2) % 3]
            e = vk - vj
            w = vi - vj
            perp = w - e * ((w * e).sum(1) / np.maximum((e * e).sum(1), 1e-300))[:, None]
            inward.append(perp / np.maximum(np.linalg.norm(perp, axis=1), 1e-300)[:, None])
        edge, corner = self._creases
        zero = (bary <= 1e-9) & ok[:, None]
        on = zero & edge[face]
        for j in range(3):  # at vertex j (its two other barycentrics 0) that ends a crease neither
            # of whose edges is one: off both edges at j
            a, b = (j + 1) % 3, (j + 2) % 3
            at = zero[:, a] & zero[:, b] & corner[face, j] & ~on[:, a] & ~on[:, b]
            on[at, a] = True
            on[at, b] = True
        one = on.sum(axis=1) == 1
        for i in range(3):
            sel = one & on[:, i]
            move[sel] = k * inward[i][sel]
        two = on.sum(axis=1) == 2
        for i in range(3):  # at vertex i: on the edges opposite the other two vertices
            sel = two & ~on[:, i]
            n1, n2 = inward[(i + 1) % 3][sel], inward[(i + 2) % 3][sel]
            move[sel] = k * (n1 + n2) / np.maximum(1.0 + (n1 * n2).sum(1), 1e-12)[:, None]
        to_c = tri.mean(axis=1) - pos
        cap = 0.25 * np.linalg.norm(to_c, axis=1)
        length = np.linalg.norm(move, axis=1)
        move *= np.minimum(1.0, cap / np.maximum(length, 1e-300))[:, None]
        return pos + move

    def _lattice(self, faces, face_s, cell_m):
        """Lattice points of ``faces`` (s = ``face_s`` subdivisions each), merged per component in
        cells of side ``cell_m`` and octahedral normal cells (8×8). Returns the lattice's start
        per face, the sample of every lattice point, and per sample its position, normal and face."""
        scene = self.scene
        counts = (face_s + 1) * (face_s + 2) // 2
        lat_start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        pos = np.zeros((int(counts.sum()), 3))
        nrm = np.zeros_like(pos)
        _lattice_points(scene.vertices, scene.faces[faces], scene.corner_normal[faces].astype(np.float64), face_s,
                        lat_start, pos, nrm)
        point_face = np.repeat(faces, counts)
        comp = scene.component_of_face[point_face]
        cell = np.floor(pos / cell_m).astype(np.int64)
        key = np.column_stack([comp, cell, _oct_cells(nrm, 8)])
        ids = _row_ids(key)
        n = int(ids.max()) + 1
        members = np.bincount(ids, minlength=n).astype(np.float64)
        mean = np.column_stack([np.bincount(ids, pos[:, c], n) for c in range(3)]) / members[:, None]
        # each sample sits at its member nearest the members' mean: on the surface, not
        # inside a curved one (a mean of points on a convex surface lies below it)
        dist = np.linalg.norm(pos - mean[ids], axis=1)
        order = np.lexsort((dist, ids))
        first = order[np.searchsorted(ids[order], np.arange(n))]
        return lat_start, ids, pos[first], nrm[first], point_face[first]

    def _row_flags(self, sample_face):
        """Rows 2i (front) always exist; 2i+1 (back) for samples on open components."""
        valid = np.zeros(2 * len(sample_face), dtype=bool)
        valid[0::2] = True
        valid[1::2] = self.scene.two_sided[self.scene.component_of_face[sample_face]]
        return valid

    def _unburied(self, valid, raw, row0=0):
        """Rows solved for: existing, and not buried in another part (over a quarter of their
        rays hit the inside of a closed shell)."""
        ok = valid.copy()
        ok[raw["rows"][raw["buried"] > _BURIED_FRACTION * self.G] - row0] = False
        return ok

    def _cast(self, pos, nrm, rows_all, key_base, assemble=None):
        """The cache rays of the listed rows (sample ``row // 2`` of ``pos``/``nrm``, ascending),
        binned on the coarse lattice: hits, blocked sky cells, glossy continuations, and per row
        the rays that hit the inside of a closed shell (``buried``) or any surface nearer than
        _CONTACT_DISTANCE lattice spacings (``near``). With ``assemble`` = (valid, row0), rows
        whose columns' aliases are known already (the contact rows): each chunk sums its rows'
        entries of W_ss, W_sb and the glossy W_g itself (:func:`_csr_sum`, rows not
        :meth:`_unburied` left empty) and keeps only those rows' glint records
        (:meth:`_glossy_summed`), which :meth:`_matrices` stacks, instead of listing every hit:
        the same matrices bit for bit (a row's entries come from one chunk, in the same order),
        without the lists' copies (~3 entries per cache ray: 36 M for Hubble's 12 M contact rays)."""
        scene = self.scene
        G = self.G
        chunk = max(1, presets.CAST_CHUNK_RAYS // G)
        raw = {k: [] for k in ("hit_rows", "hit_cols", "hit_w", "blk_rows", "blk_cells", "g_rows", "g_cols", "g_w",
                               "gb_rows", "gb_cells", "gb_w", "ss", "sb", "g_sum")}
        rec = {k: [] for k in ("row", "face", "u", "v", "side", "n", "wo")}
        glossy_face = self.glossy_comp[scene.component_of_face]
        any_glossy = bool(glossy_face.any())
        corner_normal = scene.corner_normal.astype(np.float64) if any_glossy else None
        buried = np.zeros(len(rows_all), dtype=np.int64)
        near = np.zeros(len(rows_all), dtype=np.int64)

        def one(a):
            """Chunk ``a``'s pieces of ``raw`` and ``rec`` (its rows of buried and near in place)."""
            part = {k: [] for k in raw}
            part_rec = {k: [] for k in rec}
            rows = rows_all[a:a + chunk]
            n = len(rows) * G
            o = np.empty((n, 3), dtype=np.float32)
            d = np.empty((n, 3), dtype=np.float32)
            _cache_rays(rows, pos, nrm, self.eps_m, 8, G // 8, o, d)
            h = scene.intersect(o, d, robust=True)
            hr = np.empty(n, np.int64)
            hc = np.empty((n, 3), np.int64)
            hw = np.empty((n, 3), np.float64)
            nh = _bin_hits(G, d, h["geomID"], h["primID"], h["u"].astype(np.float64), h["v"].astype(np.float64),
                           scene.face_offset, scene.face_normal, self.two_sided_face, self._c_face_s,
                           self._c_lat_start, self._c_lat_ids, hr, hc, hw, buried[a:a + len(rows)])
            blocked = np.flatnonzero(h["geomID"] >= 0)
            close = blocked[h["tfar"][blocked] < _CONTACT_DISTANCE * self.spacing_m]
            near[a:a + len(rows)] = np.bincount(close // G, minlength=len(rows))
            cells = np.empty(len(blocked), np.int64)
            _ray_cells(d, blocked, self.n_cells, cells)
            if assemble is None:
                part["hit_rows"].append(rows[hr[:nh] // G])
                part["hit_cols"].append(hc[:nh])
                part["hit_w"].append(hw[:nh])
                part["blk_rows"].append(rows[blocked // G])
                part["blk_cells"].append(cells)
            else:
                valid, row0 = assemble
                ok = valid[rows - row0] & ~(buried[a:a + len(rows)] > _BURIED_FRACTION * G)  # as _unburied
                ss, sb = self._summed(hr[:nh] // G, self._c_alias[hc[:nh]], hw[:nh], blocked // G, cells, ok)
                part["ss"].append(ss)
                part["sb"].append(sb)
            if any_glossy:
                self._glossy_chunk(rows, o, d, h, glossy_face, corner_normal, key_base + a, part, part_rec)
                if assemble is not None:
                    self._glossy_summed(rows, ok, part, part_rec)
            return part, part_rec

        starts = range(0, len(rows_all), chunk)
        # the chunks (of about presets.CAST_CHUNK_RAYS rays) two at a time on a side pool
        # (raytrace._threads.submit; presets.CAST_CHUNKS_ON_TWO_THREADS) where this thread has two
        # cores: numba's threads, or the serial builds on free cores (raytrace._jit.serial_builds);
        # False: one after the other. The same cache bit for bit (tests/raytrace/test_cache_solve.py);
        # the four built-in targets' caches built in 0.71–0.85× the time on numba's two threads,
        # 0.60–0.64× on the serial builds (BENCHMARKS.md, "Building the radiance cache")
        if presets.CAST_CHUNKS_ON_TWO_THREADS and side_cores() > 1 and len(starts) > 1:
            # a chunk's NumPy steps run on one core, which the other chunk's Embree and kernels
            # then use; every ray is keyed by its row, so the pieces are the same bits in any
            # order, and they are put back in chunk order
            parts = [f.result() for f in [submit("cache", 2, one, a) for a in starts]]
        else:
            parts = [one(a) for a in starts]
        for part, part_rec in parts:
            for k, v in part.items():
                raw[k] += v
            for k, v in part_rec.items():
                rec[k] += v
        raw.update(rows=rows_all, buried=buried, near=near, rec=rec, assembled=assemble is not None)
        return raw

    def _glossy_summed(self, rows, ok, part, rec):
        """In place, for a chunk of rows whose columns' aliases are known (``_cast``'s
        ``assemble``): its glossy continuations summed into its piece of W_g (:func:`_csr_sum`,
        rows not ``ok`` left empty; every chunk has one) rather than listed, and its glint records
        of rows not ``ok`` dropped: the same matrix and records bit for bit as from the lists (a
        row's entries come from one chunk, in the same order), without their copies (Hubble's
        contact rows: 14 M continuations, 16 M records)."""
        hit = bool(part["g_rows"])  # _glossy_chunk appends to all its lists or to none
        cols = part["g_cols"][0] if hit else np.empty((0, 3), np.int64)
        local = np.searchsorted(rows, part["g_rows"][0]) if hit else np.empty(0, np.int64)
        weights = part["g_w"][0] if hit else np.empty((0, 3, 3))
        part["g_sum"].append(_csr_sum(local, self._c_alias[cols], weights, ok[local], len(rows), len(self._c_alias)))
        part["g_rows"], part["g_cols"], part["g_w"] = [], [], []
        if hit:
            keep = ok[np.searchsorted(rows, rec["row"][0])]
            for k, v in rec.items():
                rec[k] = [v[0][keep]]

    def _matrices(self, raw, ok, row0, n_rows):
        """The transfer matrices of the rows ``row0 …`` cast in ``raw`` (rows not ``ok`` left
        empty), columns on the coarse lattice: a hit on a buried coarse row counts for the row
        standing in for it. The chunks' pieces are freed as they are stacked (``raw``'s lists of
        them emptied; its ``rows`` and ``near`` kept): with a CAD mesh's glint records they are
        gigabytes, and stacking them all while every piece lives doubled the build's peak."""
        G = self.G
        alias = self._c_alias
        n_c = len(alias)

        def cat(k, shape):
            return np.concatenate(raw[k]) if raw[k] else np.empty(shape, np.int64)

        if raw["ss"]:  # summed per chunk by _cast: stacked in row order
            ss, sb, rows = raw["ss"], raw["sb"], raw["rows"] - row0
        else:  # from the lists of every hit
            hw = np.concatenate(raw["hit_w"]) if raw["hit_w"] else np.empty((0, 3))
            pieces = self._summed(cat("hit_rows", 0) - row0, alias[cat("hit_cols", (0, 3))], hw,
                                  cat("blk_rows", 0) - row0, cat("blk_cells", 0), ok)
            ss, sb, rows = [pieces[0]], [pieces[1]], np.arange(n_rows)
        out = {"W_ss": _stack_rows(ss, rows, n_rows, n_c), "W_sb": _stack_rows(sb, rows, n_rows, self.n_cells ** 2)}
        ss.clear()
        sb.clear()
        out["W_g"], out["W_gb"], out["glint"] = None, None, None
        assembled = raw.get("assembled", False)  # W_g summed and the records kept per chunk by _cast
        if raw["gb_rows"]:  # _glossy_chunk appends to all its lists or to none (W_g's, summed, are emptied)
            # one CSR pattern with RGB entries: (indptr, indices, data (nnz, 3)), the entries
            # summed in input order, then divided by G
            if assembled:
                indptr, indices, data = _stack_pieces(raw["g_sum"], raw["rows"] - row0, n_rows)
                raw["g_sum"].clear()
            else:
                gr = np.concatenate(raw["g_rows"]) - row0
                gc = alias[np.concatenate(raw["g_cols"])]
                gw = np.concatenate(raw["g_w"])  # (hit, lattice point, channel)
                for k in ("g_rows", "g_cols", "g_w"):
                    raw[k].clear()
                indptr, indices, data = _csr_sum(gr, gc, gw, ok[gr], n_rows, n_c)
                del gr, gc, gw
            data /= G
            out["W_g"] = (indptr, indices.astype(np.int64, copy=False), data)
            del indptr, indices, data
            bbr = np.concatenate(raw["gb_rows"]) - row0
            bbc = np.concatenate(raw["gb_cells"])
            bbw = np.concatenate(raw["gb_w"])
            kb = ok[bbr]
            # (SciPy's: _csr_sum's order of summing duplicates, the input's, differs from it in the
            # last bit of ~1 % of these entries, and these matrices are small)
            out["W_gb"] = [sp.csr_matrix((bbw[kb, c] / G, (bbr[kb], bbc[kb])), shape=(n_rows, self.n_cells ** 2))
                           for c in range(3)]
            rec = raw["rec"]
            rr = np.concatenate(rec["row"]) - row0
            keep = None if assembled else ok[rr]  # assembled: the chunks kept only rows ok
            rk = rr if keep is None else rr[keep]
            # the chunks go in row order, so the records mostly are already: no reordering then
            order = None if np.all(rk[1:] >= rk[:-1]) else np.argsort(rk, kind="stable")
            glint = {}
            for k, v in rec.items():
                a = np.concatenate(v) if keep is None else np.concatenate(v)[keep]
                v.clear()
                glint[k] = np.ascontiguousarray(a if order is None else a[order])
                del a
            glint["row"] = glint["row"] - row0
            glint["ptr"] = np.searchsorted(glint["row"], np.arange(n_rows + 1)).astype(np.int64)
            out["glint"] = glint
        return out

    def _summed(self, hit_rows, hit_cols, hit_w, blk_rows, blk_cells, ok):
        """:func:`_csr_sum`'s W_ss and W_sb of ``len(ok)`` rows (those not ``ok`` left empty) from
        their cache rays' hits (rows, aliased lattice columns (n, 3), interpolation weights
        (n, 3)) and their blocked rays (rows, sky cells): each ray counts 1/G."""
        G = self.G
        ss = _csr_sum(hit_rows, hit_cols, (hit_w / G)[:, :, None], ok[hit_rows], len(ok), len(self._c_alias))
        sb = _csr_sum(blk_rows, blk_cells[:, None], np.full((len(blk_rows), 1, 1), 1.0 / G), ok[blk_rows], len(ok),
                      self.n_cells ** 2)
        return ss, sb

    def _glossy_chunk(self, rows, o, d, h, glossy_face, corner_normal, key0, raw, rec):
        """The cache rays of one chunk that hit a glossy part (on a side that has a row): one
        ray drawn from the part's lobe at each hit, binned like the cache's own rays (the
        lattice points it hits, or the sky cell it leaves through, with the lobe's RGB weight),
        and the hit itself recorded for the Sun's specular reflection per frame."""
        scene = self.scene
        G = self.G
        geom = h["geomID"]
        hit = np.flatnonzero(geom >= 0)
        f = scene.face_offset[geom[hit]] + h["primID"][hit]
        front = np.einsum("ij,ij->i", d[hit].astype(np.float64), scene.face_normal[f]) < 0.0
        sel = glossy_face[f] & (front | self.two_sided_face[f])
        idx = hit[sel].astype(np.int64)
        if not len(idx):
            return
        m = len(idx)
        o2, d2, w2, n2 = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
        hu, hv = h["u"].astype(np.float64), h["v"].astype(np.float64)
        _glossy_bounce(idx, o.astype(np.float64), d.astype(np.float64), h["tfar"].astype(np.float64), geom,
                       h["primID"], hu, hv, scene.face_offset, scene.face_normal,
                       corner_normal, scene.component_of_face, self.f0, self.alpha,
                       self.eps_m, int(key0) * G, o2, d2, w2, n2)
        src = rows[idx // G]
        h2 = scene.intersect(o2, d2, robust=True)
        hr = np.empty(m, np.int64)
        hc = np.empty((m, 3), np.int64)
        hw = np.empty((m, 3), np.float64)
        nh = _bin_hits(1, d2, h2["geomID"], h2["primID"], h2["u"].astype(np.float64), h2["v"].astype(np.float64),
                       scene.face_offset, scene.face_normal, self.two_sided_face, self._c_face_s, self._c_lat_start,
                       self._c_lat_ids, hr, hc, hw, np.zeros(m, np.int64))
        raw["g_rows"].append(src[hr[:nh]])
        raw["g_cols"].append(hc[:nh])
        raw["g_w"].append(hw[:nh, :, None] * w2[hr[:nh]][:, None, :])
        esc = np.flatnonzero(h2["geomID"] < 0).astype(np.int64)
        cells = np.empty(len(esc), np.int64)
        _ray_cells(d2, esc, self.n_cells, cells)
        raw["gb_rows"].append(src[esc])
        raw["gb_cells"].append(cells)
        raw["gb_w"].append(w2[esc])
        rec["row"].append(src)
        rec["face"].append(f[sel].astype(np.int64))
        rec["u"].append(hu[idx])
        rec["v"].append(hv[idx])
        rec["side"].append((~front[sel]).astype(np.int64))
        rec["n"].append(n2.astype(np.float32))
        rec["wo"].append((-d[idx] / np.linalg.norm(d[idx], axis=1, keepdims=True)).astype(np.float32))

    @staticmethod
    def _aliases(pos, nrm, comp, bad_rows, ok) -> np.ndarray:
        """For every row in ``bad_rows`` (buried), the nearest ``ok`` row of the same component
        and side whose normal is within 60° (else the nearest of the same component and side,
        else itself), rows 2i, 2i+1 at sample i of ``pos``/``nrm``: buried rows take its values,
        so a surface point next to a junction is never dark."""
        n_rows = len(ok)
        alias = np.arange(n_rows)
        buried = np.flatnonzero(bad_rows)
        if len(buried) == 0:
            return alias
        for side in (0, 1):
            good = np.flatnonzero(ok & (np.arange(n_rows) % 2 == side))
            bad = buried[buried % 2 == side]
            if len(good) == 0 or len(bad) == 0:
                continue
            tree = cKDTree(pos[good // 2])
            k = min(16, len(good))
            _, nn = tree.query(pos[bad // 2], k=k)
            nn = good[nn.reshape(len(bad), k)]
            same = comp[nn] == comp[bad][:, None]
            close = same & (np.einsum("ij,ikj->ik", nrm[bad // 2], nrm[nn // 2]) > 0.5)
            for mask in (same, close):  # prefer close in normal, else same component
                has = mask.any(axis=1)
                alias[bad[has]] = nn[has, mask[has].argmax(axis=1)]
        return alias

    def solve(self, lighting, *, max_iterations: int = 64, tolerance: float = 1e-3,
              env_irradiance: np.ndarray | None = None) -> CacheFrame:
        """Irradiance and outgoing radiance of every row under ``lighting``
        (:class:`raytrace.lighting.Lighting`), all bounces: Gauss–Seidel sweeps until one changes
        no value by more than ``tolerance`` times the largest source term; contact rows gather
        once from the solution. ``env_irradiance``: the environment's
        unoccluded irradiance table of this lighting (:func:`raytrace.environment.irradiance_table`),
        if the caller already has it."""
        p, tex = lighting.packed()
        L_env = env.env_cells(p, tex, self.n_cells, 4)
        table = env_irradiance if env_irradiance is not None else env.irradiance_table(p, tex)
        c = self._c
        E_sun, E0 = self._sources(self._c_ray_pos, self._c_nrm, self._c_solved, c, lighting, table, L_env, None)
        E = E0.copy()
        Y = self._c_rho_ss * E
        W = c["W_ss"]
        it = 0
        scale = max(float(np.abs(E0).max()), 1e-30) if len(E0) else 1e-30
        glossy = c["W_g"] is not None
        W_g = c["W_g"] if glossy else _EMPTY_CSR3(self.n_coarse_rows)
        Yb = self._c_rho_bounce * E if glossy else np.empty((0, 3))
        # over-relaxed sweeps (presets.SOR_OMEGA; 1: none). ω = 1.2 took the 1/90 caches of the
        # built-in targets 12–15 → 9–11 sweeps (Spacedragon 5–7 → 6) to the same tolerance, nearer
        # the exact solution; ω = 1.3–1.4 failed on Cassini, so a sweep whose residual grows drops
        # back to ω = 1 (BENCHMARKS.md, "Over-relaxed sweeps for the radiance cache")
        omega = presets.SOR_OMEGA
        last = math.inf
        for it in range(1, max_iterations + 1):
            delta = _gauss_seidel_sweep(W.indptr, W.indices, W.data, *W_g, self._c_rho_ss, self._c_rho_bounce,
                                        E0, E, Y, Yb, omega)
            if delta <= tolerance * scale:
                break
            if omega != 1.0 and it > 2 and delta > last:
                # the residual grew: over-relaxation is not converging on this transfer (two
                # facing surfaces); Gauss–Seidel converges from any iterate
                omega = 1.0
            last = delta
        unsolved = self._c_unsolved_rows
        _zero_rows(E, unsolved)
        _zero_rows(Y, unsolved)  # ρ ⊙ E still, exactly
        if glossy:
            _zero_rows(Yb, unsolved)
        f = self._f
        E_f = E_sun_f = np.empty((0, 3))
        if f is not None:
            # contact rows: one gather from the solved coarse rows (their own rays, their sources)
            E_sun_c = E_sun[self._c_alias]
            E_sun_f = f["P"] @ E_sun_c
            E0_f = self._sources(f["ray_pos"], f["nrm"], f["solved"], f, lighting, table, L_env, E_sun_c, E_sun_f)[1]
            if f["W_g"] is not None and not glossy:
                Yb = np.multiply(self._c_rho_bounce, E)
            W_f = f["W_ss"]
            E_f = np.empty_like(E0_f)
            _jacobi_step(W_f.indptr, W_f.indices, W_f.data, Y,
                         *(f["W_g"] if f["W_g"] is not None else _EMPTY_CSR3(len(E0_f))), Yb, E0_f, E0_f, E_f)
            _zero_rows(E_f, f["unsolved_rows"])
            E_f[f["passive"]] = f["P_passive"] @ E[self._c_alias]
        n = len(self._alias)
        E_out, sun_out = np.empty((n, 3)), np.empty(n)
        indirect, L_out = np.empty((n, 3)), np.empty((n, 3))
        _lookup_rows(self._alias, self.n_coarse_rows, E, E_f, E_sun, np.ascontiguousarray(E_sun_f).reshape(-1),
                     self._rho_over_pi, E_out, sun_out, indirect, L_out)
        return CacheFrame(E_out, sun_out, L_out, it, indirect)

    def direct_environment(self, envs, rows) -> list:
        """The environment's light that reaches the lookup rows ``rows`` directly, for each
        environment (p, tex, table) of ``envs`` (:meth:`raytrace.lighting.Lighting.packed` or a
        part of it — Earth alone, the sky alone — and its unoccluded irradiance table,
        :func:`raytrace.environment.irradiance_table`): E_env(n) − π W_sb L_env, the open sky
        minus the sky the row's rays block, the source term of :meth:`solve` without the Sun
        and without the light the parts reflect (bounces, glossy reflections, glints); on
        contact rows that interpolate the coarse ones, their interpolation, as there. Per
        environment an array (lookup rows, 3) [W/m²] whose listed rows are set (the others
        are not). Linear in the environment's radiance: the terms of Earth alone and of the
        sky alone sum to the full environment's; what :meth:`solve`'s ``indirect_W_m2`` holds
        beyond them is inter-reflected light. Computed for the listed rows only (those a
        frame's pixels read), not the whole cache."""
        from ._light_kernels import environment_rows
        c, f = self._c, self._f
        if f is None:
            empty_i, empty_f = np.zeros(1, np.int32), np.zeros(0)
            f_args = (np.zeros(0, bool), np.zeros((0, 3)), empty_i, empty_i, empty_f, np.zeros(0, np.int64),
                      np.zeros(1, np.int32), empty_i, empty_f)
        else:
            if "passive_pos" not in f:
                f["passive_pos"] = np.full(len(f["solved"]), -1, np.int64)
                f["passive_pos"][f["passive"]] = np.arange(len(f["passive"]))
            W, P = f["W_sb"], f["P_passive"]
            f_args = (f["solved"], f["nrm"], W.indptr, W.indices, W.data, f["passive_pos"], P.indptr, P.indices,
                      P.data)
        W = c["W_sb"]
        rows = np.asarray(rows, dtype=np.int64)
        out = []
        for p, tex, table in envs:
            D = np.empty((len(self._alias), 3))
            environment_rows(rows, self._alias, self.n_coarse_rows, self._c_solved, self._c_nrm, W.indptr, W.indices,
                             W.data, *f_args, self._c_alias, env.env_cells(p, tex, self.n_cells, 4), table, D)
            out.append(D)
        return out

    def _sources(self, pos, nrm, solved, mats, lighting, table, L_env, E_sun_hits, E_sun=None):
        """Direct sunlight (one shadow ray per solved row, unless given as ``E_sun``) and the
        source term E0 (sunlight, open sky minus the sky the row's rays block, glossy reflections
        of sky and Sun) of the rows of ``pos``/``nrm`` with transfer matrices ``mats``.
        ``E_sun_hits``: the coarse rows' sunlight (aliased) for the glints, None when these are
        the coarse rows themselves."""
        n = len(solved)
        rows = np.flatnonzero(solved).astype(np.int64)
        e_sun = lighting.sun_irradiance_at_target_W_m2
        given = E_sun is not None
        if not given:
            E_sun = np.zeros(n)
        if e_sun > 0.0 and len(rows) and not given:
            o = np.empty((len(rows), 3), np.float32)
            d = np.empty((len(rows), 3), np.float32)
            cosv = np.empty(len(rows))
            _sun_rays(rows, pos, nrm, self.eps_m, lighting.sun_record(), cosv, o, d)
            lit = cosv > 0.0
            seen = ~self.scene.occluded(o[lit], d[lit], robust=True)
            vals = np.zeros(len(rows))
            vals[np.flatnonzero(lit)[seen]] = e_sun * cosv[lit][seen]
            E_sun[rows] = vals
        E_open = np.zeros((n, 3))
        # the rows' cells and weights in the table, the same every frame: found once per table shape
        corners = mats.get("table_corners")
        if corners is None or corners[0] != table.shape[:2]:
            idx, w = np.empty((len(rows), 3), np.int64), np.empty((len(rows), 4))
            _irradiance_corners(table.shape[0], table.shape[1], nrm, rows, idx, w)
            corners = mats["table_corners"] = (table.shape[:2], idx, w)  # one assignment: thread-safe
        _rows_irradiance(table, rows, corners[1], corners[2], E_open)
        # E0 = E_sun + E_open − π W_sb L_env, the product row-parallel (scipy's is one thread)
        E_open += E_sun[:, None]
        W_sb = mats["W_sb"]
        E0 = np.empty((n, 3))
        sky = -math.pi * L_env
        _jacobi_step(W_sb.indptr, W_sb.indices, W_sb.data, sky, *_EMPTY_CSR3(n), sky, E_open, E_open, E0)
        if mats["W_g"] is not None:
            for c in range(3):
                E0[:, c] += math.pi * (mats["W_gb"][c] @ L_env[:, c])
            if e_sun > 0.0:
                gl = mats["glint"]
                hits = E_sun[self._c_alias] if E_sun_hits is None else E_sun_hits
                if "lattice_rows" not in gl:  # the records' lattice rows, the same every frame: found once
                    rows, w = np.empty((len(gl["face"]), 3), np.int32), np.empty((len(gl["face"]), 3))
                    _glint_lattice(gl["face"], gl["u"], gl["v"], gl["side"], self._c_valid, self._c_face_s,
                                   self._c_lat_start, self._c_lat_ids, rows, w)
                    gl["lattice_w"] = w
                    gl["lattice_rows"] = rows  # last: another thread's frame tests for it
                _glints(gl["ptr"], gl["face"], gl["lattice_rows"], gl["lattice_w"], gl["n"], gl["wo"],
                        self.scene.component_of_face, self.f0, self.alpha, hits, lighting.sun_record(),
                        math.pi / self.G, E0)
        return E_sun, E0
