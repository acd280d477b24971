"""The radiance cache's per-frame solve against a direct sparse solve of the same system.

``RadianceCache.solve`` iterates (Gauss–Seidel sweeps) on E = E0 + W_ss (ρ ⊙ E) + W_g (ρ_b ⊙ E).
Here the same matrices and source term go through a sparse LU factorisation
(``scipy.sparse.linalg.spsolve``, one channel at a time), a second method that shares nothing
with the iteration but its input. The scene is an open box whose white walls and gold floor
face each other, so light bounces many times (slow modes) and the glossy transfer W_g is
present."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from scipy.sparse.linalg import spsolve

from raytrace import _cache_kernels, environment as env, presets
from raytrace.lighting import Lighting
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene


def _open_box():
    parts = [Component("floor", _plate((4.0, 4.0, 0.05), (0.0, 0.0, -0.025)), "gold_mli", "bus", 1.0)]
    for k, (size, at) in enumerate((((0.05, 4.0, 3.0), (2.025, 0.0, 1.5)), ((0.05, 4.0, 3.0), (-2.025, 0.0, 1.5)),
                                    ((4.0, 0.05, 3.0), (0.0, 2.025, 1.5)), ((4.0, 0.05, 3.0), (0.0, -2.025, 1.5)))):
        parts.append(Component(f"wall{k}", _plate(size, at), "white_paint", "bus", 1.0))
    return Scene(TargetModel("open box", tuple(parts)))


def _plate(size, at):
    m = trimesh.creation.box(size)
    m.apply_translation(at)
    return m


def _source_term(cache, lighting):
    """The coarse rows' source term E0 of the cache's solve under ``lighting``."""
    p, tex = lighting.packed()
    L_env = env.env_cells(p, tex, cache.n_cells, 4)
    table = env.irradiance_table(p, tex)
    return cache._sources(cache._c_ray_pos, cache._c_nrm, cache._c_solved, cache._c, lighting, table, L_env, None)[1]


def _direct_solution(cache, lighting):
    """E on the coarse rows by LU, per channel, from the cache's own matrices and sources."""
    c = cache._c
    E0 = _source_term(cache, lighting)
    n = cache.n_coarse_rows
    E = np.zeros((n, 3))
    for ch in range(3):
        A = sp.identity(n, format="csr") - c["W_ss"] @ sp.diags(cache._c_rho_ss[:, ch])
        if c["W_g"] is not None:
            g_ptr, g_idx, g_data = c["W_g"]
            A = A - sp.csr_matrix((g_data[:, ch], g_idx, g_ptr), shape=(n, n)) @ sp.diags(cache._c_rho_bounce[:, ch])
        E[:, ch] = spsolve(A.tocsc(), E0[:, ch])
    E[~cache._c_solved] = 0.0
    return E, float(np.abs(E0).max())


def test_solve_matches_a_direct_sparse_solve_and_does_not_depend_on_threads():
    scene = _open_box()
    cache = scene.radiance_cache(spacing_m=0.4, contact_refine=False)
    assert cache._c["W_g"] is not None and cache._f is None  # glossy transfer present, no contact rows
    sun = np.array([0.3, -0.2, 1.0])
    lighting = Lighting(sun_dir_body=sun / np.linalg.norm(sun), sun_irradiance_W_m2=1361.0,
                        ambient_radiance_W_m2_sr=1.0)
    E_lu, scale = _direct_solution(cache, lighting)
    E_lu = E_lu[cache._alias]
    indirect_share = float(np.abs(E_lu - E_lu.min()).max())
    assert indirect_share > 0.0

    tight = cache.solve(lighting, tolerance=1e-13, max_iterations=5000)
    assert tight.iterations < 5000
    np.testing.assert_allclose(tight.irradiance_W_m2, E_lu, rtol=0.0, atol=1e-9 * scale)

    frame = cache.solve(lighting)  # the renderer's tolerance, 1e-3 of the largest source
    assert 1 < frame.iterations < 64
    err = np.abs(frame.irradiance_W_m2 - E_lu).max()
    assert err <= 5e-3 * scale, err / scale
    # the bounce light is far above that error: a solve that stopped after one sweep would fail
    one = cache.solve(lighting, max_iterations=1)
    assert np.abs(one.irradiance_W_m2 - E_lu).max() > 10.0 * err

    # the per-row products come from the solved irradiance exactly
    np.testing.assert_array_equal(frame.indirect_W_m2, frame.irradiance_W_m2 - frame.sun_irradiance_W_m2[:, None])
    np.testing.assert_array_equal(frame.radiance_out, cache.rho_bounce / math.pi * frame.irradiance_W_m2)

    # one thread or all: the same bits
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        single = cache.solve(lighting)
    finally:
        numba.set_num_threads(threads)
    for a, b in ((single.irradiance_W_m2, frame.irradiance_W_m2), (single.radiance_out, frame.radiance_out),
                 (single.sun_irradiance_W_m2, frame.sun_irradiance_W_m2)):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("omega", [1.0, 1.95])
def test_the_over_relaxed_solve_converges_to_the_direct_solve_or_falls_back(monkeypatch, omega):
    """The sweeps are over-relaxed (presets.SOR_OMEGA); where that does not converge, a sweep
    whose residual grows drops back to Gauss–Seidel. ω = 1.95 is far past where the open box's
    facing walls and floor let over-relaxation converge quickly: the solve must still reach the
    LU solution, and ω = 1 (plain Gauss–Seidel) must too."""
    import raytrace.cache as cache_module
    monkeypatch.setattr(presets, "SOR_OMEGA", omega)
    omegas = []
    sweep = cache_module._gauss_seidel_sweep

    def spy(*a):
        omegas.append(a[-1])
        return sweep(*a)

    monkeypatch.setattr(cache_module, "_gauss_seidel_sweep", spy)
    scene = _open_box()
    cache = scene.radiance_cache(spacing_m=0.4, contact_refine=False)
    sun = np.array([0.3, -0.2, 1.0])
    lighting = Lighting(sun_dir_body=sun / np.linalg.norm(sun), sun_irradiance_W_m2=1361.0,
                        ambient_radiance_W_m2_sr=1.0)
    E_lu, scale = _direct_solution(cache, lighting)
    tight = cache.solve(lighting, tolerance=1e-11, max_iterations=5000)
    assert tight.iterations < 5000
    assert omegas[0] == omega and omegas[-1] == 1.0  # the switch's ω first, plain Gauss–Seidel at the end
    np.testing.assert_allclose(tight.irradiance_W_m2, E_lu[cache._alias], rtol=0.0, atol=1e-8 * scale)
    frame = cache.solve(lighting)
    assert np.abs(frame.irradiance_W_m2 - E_lu[cache._alias]).max() <= 5e-3 * scale
    if omega > 1.5:
        # the fallback is what converged: as many sweeps at ω = 1.95 throughout are far off
        c = cache._c
        E0 = _source_term(cache, lighting)
        E = E0.copy()
        Y, Yb = cache._c_rho_ss * E, cache._c_rho_bounce * E
        for _ in range(tight.iterations):
            _cache_kernels._gauss_seidel_sweep(c["W_ss"].indptr, c["W_ss"].indices, c["W_ss"].data, *c["W_g"],
                                               cache._c_rho_ss, cache._c_rho_bounce, E0, E, Y, Yb, omega)
        E[~cache._c_solved] = 0.0
        assert np.abs(E - E_lu).max() > 1e-2 * scale


def _same(a, b, where):
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    elif sp.issparse(a):
        for part in ("indptr", "indices", "data"):
            assert np.array_equal(getattr(a, part), getattr(b, part)), f"{where}.{part}"
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True), where
    else:
        assert a == b, where


def test_cache_rays_in_chunks_on_two_threads_build_the_same_cache(monkeypatch):
    """``RadianceCache._cast`` runs its chunks of rays two at a time (raytrace._threads): the
    matrices, glossy records and per-row flags are the same bits as one chunk after another,
    and with one numba thread; and two at a time on the serial builds (``serial_builds``: a
    fresh install's scenes built for the pool's workers). Chunks of 16 rows, so the box's rows
    (coarse and contact) make dozens of them."""
    import contextlib

    from raytrace import cache as cache_mod
    from raytrace._jit import serial_builds
    if numba.get_num_threads() < 2:
        pytest.skip("one numba thread: the chunks run one after the other")
    monkeypatch.setattr(presets, "CAST_CHUNK_RAYS", 16 * 128)
    submitted, chunk_threads = [], set()
    submit = cache_mod.submit

    def spy(name, workers, fn, *args):
        submitted.append(name)

        def counted(*a):
            chunk_threads.add(numba.get_num_threads())
            return fn(*a)
        return submit(name, workers, counted, *args)

    monkeypatch.setattr(cache_mod, "submit", spy)
    built, on_pool, threads_seen = [], [], []
    n = numba.get_num_threads()
    for two, threads, ctx in ((True, n, contextlib.nullcontext), (False, n, contextlib.nullcontext),
                              (True, 1, contextlib.nullcontext), (True, n, lambda: serial_builds(2))):
        monkeypatch.setattr(presets, "CAST_CHUNKS_ON_TWO_THREADS", two)
        old = numba.get_num_threads()
        numba.set_num_threads(threads)
        submitted.clear()
        chunk_threads.clear()
        try:
            with ctx():
                built.append(_open_box().radiance_cache(spacing_m=0.4))
        finally:
            numba.set_num_threads(old)
        on_pool.append(len(submitted))
        threads_seen.append(set(chunk_threads))
    assert numba.get_num_threads() == n  # serial_builds restored the thread count
    # the side pool ran the first and the last build, the last on one numba thread per chunk
    assert on_pool[0] > 4 and on_pool[1:3] == [0, 0] and on_pool[3] == on_pool[0]
    assert threads_seen[0] == {n} and threads_seen[3] == {1}
    first = built[0]
    assert first._f is not None and first._c["W_g"] is not None  # contact rows and glossy transfer present
    assert first.n_coarse_rows > 4 * 16
    members = [k for k in dir(first) if not k.startswith("__") and k != "scene"
               and not callable(getattr(first, k))]
    for other in built[1:]:
        for k in members:
            _same(getattr(first, k), getattr(other, k), k)


def test_csr_assembly_against_scipy():
    """raytrace._cache_kernels._csr_sum (the transfer matrices' assembly) against scipy's COO to CSR
    with duplicates summed: the same pattern (columns ascending per row) and values to the
    last bits' order of summation, on rows in input order and shuffled, with dropped entries,
    one and three channels, a column range not a multiple of 64 and an empty matrix."""
    from raytrace._cache_kernels import _csr_sum
    rng = np.random.default_rng(4)
    for trial in range(12):
        m, n_rows = int(rng.integers(0, 4000)), int(rng.integers(1, 400))
        n_cols = int(rng.integers(1, 70)) if trial % 3 == 0 else int(rng.integers(1, 20000))
        rows = rng.integers(0, n_rows, m)
        if trial % 2:
            rows = np.sort(rows)
        cols = rng.integers(0, n_cols, (m, 3))
        nch = 1 if trial % 4 else 3
        vals = rng.random((m, 3, nch))
        keep = rng.random(m) < 0.7
        indptr, indices, data = _csr_sum(rows, cols, vals, keep, n_rows, n_cols)
        assert indptr.shape == (n_rows + 1,) and indices.dtype == np.int32 and data.shape == (len(indices), nch)
        for ch in range(nch):
            ref = sp.csr_matrix((vals[keep][:, :, ch].ravel(), (np.repeat(rows[keep], 3), cols[keep].ravel())),
                                shape=(n_rows, n_cols))
            ref.sum_duplicates()
            assert np.array_equal(ref.indptr, indptr) and np.array_equal(ref.indices, indices), trial
            np.testing.assert_allclose(data[:, ch], ref.data, rtol=1e-13, atol=0.0)


def test_contact_rows_summed_per_chunk_give_the_listed_matrices(monkeypatch):
    """The contact rows' W_ss and W_sb, and their glossy W_g and glint records, summed (kept) by
    each chunk of rays as it is cast (``presets.ASSEMBLE_CONTACT_PER_CHUNK``) are the same bits as
    those assembled from the lists of every hit, with chunks of 16 rows (dozens of them) on one
    thread and two."""
    from raytrace import cache as cache_mod
    monkeypatch.setattr(presets, "CAST_CHUNK_RAYS", 16 * 128)
    summed = []  # rows per call of RadianceCache._summed: per chunk, or per matrix from the lists
    real = cache_mod.RadianceCache._summed

    def spy(self, *a):
        summed.append(len(a[-1]))
        return real(self, *a)

    monkeypatch.setattr(cache_mod.RadianceCache, "_summed", spy)
    built, calls = [], []
    for per_chunk, threads in ((False, 1), (True, 1), (True, max(2, numba.get_num_threads()))):
        monkeypatch.setattr(presets, "ASSEMBLE_CONTACT_PER_CHUNK", per_chunk)
        old = numba.get_num_threads()
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
        summed.clear()
        try:
            built.append(_open_box().radiance_cache(spacing_m=0.4))
        finally:
            numba.set_num_threads(old)
        calls.append(len(summed))
    # from the lists: one call for the coarse rows and one for the contact rows; per chunk: one
    # call for the coarse rows and one per chunk of contact rows (dozens)
    assert calls[0] == 2 and calls[1] > 4 and calls[2] == calls[1]
    first = built[0]
    assert first._f is not None and len(first.contact_rows) > 4 * 16
    assert first._f["W_ss"].nnz > 0 and first._f["W_sb"].nnz > 0
    g, glint = first._f["W_g"], first._f["glint"]
    assert g is not None and len(g[1]) > 0 and len(glint["row"]) > 0  # the box's glossy lid reflects
    for other in built[1:]:
        for k in ("W_ss", "W_sb"):
            a, b = first._f[k], other._f[k]
            assert a.shape == b.shape and a.has_sorted_indices and b.has_sorted_indices
            for part in ("indptr", "indices", "data"):
                x, y = getattr(a, part), getattr(b, part)
                assert x.dtype == y.dtype and np.array_equal(x.view(np.uint8), y.view(np.uint8)), (k, part)
        for x, y in zip(first._f["W_g"], other._f["W_g"]):
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x.view(np.uint8), y.view(np.uint8))
        for a, b in zip(first._f["W_gb"], other._f["W_gb"]):
            for part in ("indptr", "indices", "data"):
                assert np.array_equal(getattr(a, part), getattr(b, part)), ("W_gb", part)
        assert first._f["glint"].keys() == other._f["glint"].keys()
        for k, x in first._f["glint"].items():
            y = other._f["glint"][k]
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x.view(np.uint8), y.view(np.uint8)), k


@pytest.mark.parametrize("omega", [1.0, 1.2])
def test_a_sweep_skips_rows_without_entries_and_matches_gauss_seidel_in_numpy(omega):
    """:func:`raytrace._cache_kernels._gauss_seidel_sweep` on a random system where a third of
    the rows have no entries (as the cache's unsolved rows) against the sweep written out in
    NumPy row by row (each row from the newest values, over-relaxed): the same to rounding,
    the rows without entries left at X0, and a row without entries whose X differs from X0
    still set to it."""
    rng = np.random.default_rng(3)
    n = 60
    empty = rng.random(n) < 0.35
    W = sp.random(n, n, density=0.15, random_state=4, format="csr") * 0.1
    W = sp.diags((~empty).astype(float)) @ W
    G = sp.random(n, n, density=0.05, random_state=5, format="csr")
    G = (sp.diags((~empty).astype(float)) @ G).tocsr()
    G.sort_indices()
    W = W.tocsr()
    W.sort_indices()
    g_data = np.ascontiguousarray(np.repeat(G.data[:, None], 3, axis=1) * rng.random((G.nnz, 3)) * 0.1)
    rho, rho_b = rng.random((n, 3)), rng.random((n, 3))
    X0 = rng.random((n, 3))
    X0[empty & (rng.random(n) < 0.5)] = 0.0
    X = X0.copy()
    odd = np.flatnonzero(empty)[0]
    X[odd] += 1.0  # a row without entries away from its source
    Y, Yb = rho * X, rho_b * X
    ref_X, ref_Y, ref_Yb = X.copy(), Y.copy(), Yb.copy()
    dmax = 0.0
    for i in range(n):
        s = X0[i].copy()
        for k in range(W.indptr[i], W.indptr[i + 1]):
            s += W.data[k] * ref_Y[W.indices[k]]
        for k in range(G.indptr[i], G.indptr[i + 1]):
            s += g_data[k] * ref_Yb[G.indices[k]]
        dmax = max(dmax, float(np.abs(s - ref_X[i]).max()))
        ref_X[i] = ref_X[i] + omega * (s - ref_X[i]) if omega != 1.0 else s
        ref_Y[i], ref_Yb[i] = rho[i] * ref_X[i], rho_b[i] * ref_X[i]
    # (the index types of the cache's own matrices: SciPy's int32 for W_ss, int64 for W_g)
    d = _cache_kernels._gauss_seidel_sweep(W.indptr.astype(np.int32), W.indices.astype(np.int32), W.data,
                                           G.indptr.astype(np.int64), G.indices.astype(np.int64), g_data, rho, rho_b,
                                           X0, X, Y, Yb, omega)
    np.testing.assert_allclose(X, ref_X, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(Y, ref_Y, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(Yb, ref_Yb, rtol=1e-13, atol=1e-15)
    assert d == pytest.approx(dmax, rel=1e-13)
    rest = np.flatnonzero(empty)[1:]
    assert np.array_equal(X[rest], X0[rest])
    assert np.allclose(X[odd], X0[odd] + (1.0 - omega) * 1.0, rtol=1e-13)


def test_rows_irradiance_from_corners_found_once_is_the_bilinear_table():
    """The rows' unoccluded irradiance, from their table cells and weights found once
    (:func:`raytrace._cache_kernels._irradiance_corners`) and summed per frame
    (:func:`raytrace._cache_kernels._rows_irradiance`), against the table interpolated in NumPy
    (θ = π i/(n_t − 1), φ = 2π j/n_p, bilinear, φ wrapping), on both sides of random normals,
    the poles and the φ = 0 seam included; rows not listed are left alone."""
    rng = np.random.default_rng(8)
    nrm = rng.normal(size=(40, 3))
    nrm[:3] = [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.6, -1e-12, 0.8]]
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    table = rng.random((49, 96, 3))
    rows = np.flatnonzero(rng.random(80) < 0.7).astype(np.int64)
    idx, w = np.empty((len(rows), 3), np.int64), np.empty((len(rows), 4))
    _cache_kernels._irradiance_corners(49, 96, nrm, rows, idx, w)
    out = np.full((80, 3), -1.0)
    _cache_kernels._rows_irradiance(table, rows, idx, w, out)
    n = nrm[rows // 2] * np.where(rows % 2 == 0, 1.0, -1.0)[:, None]
    x = np.arccos(np.clip(n[:, 2], -1, 1)) / math.pi * 48
    y = np.mod(np.arctan2(n[:, 1], n[:, 0]), 2 * math.pi) / (2 * math.pi) * 96
    i = np.minimum(x.astype(int), 47)
    j = y.astype(int) % 96
    fx, fy = (x - i)[:, None], (y - np.floor(y))[:, None]
    expect = ((1 - fx) * (1 - fy) * table[i, j] + (1 - fx) * fy * table[i, (j + 1) % 96]
              + fx * (1 - fy) * table[i + 1, j] + fx * fy * table[i + 1, (j + 1) % 96])
    np.testing.assert_allclose(out[rows], expect, rtol=1e-12)
    rest = np.setdiff1d(np.arange(80), rows)
    assert (out[rest] == -1.0).all()
