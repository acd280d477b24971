"""The persistent cache (raytrace._diskcache) and what uses it: the scenes with their radiance
caches a run stores for the next (raytrace.dataset.scenes.prebuild_scenes), the GGX split-sum
table, and the small jobs rendered in this process (raytrace.dataset.pool.in_process)."""

import os
import threading
from pathlib import Path

import numpy as np
import pytest

from raytrace import _diskcache as D
from raytrace.dataset import pool, scenes


def _box_obj(path, size=(2.0, 1.0, 1.0)):
    import trimesh
    box = trimesh.creation.box(size)
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in box.vertices] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in box.faces]
    path.write_text("\n".join(lines) + "\n")
    return ("mesh", str(path), 1.0, 30.0)


def _task(spec, quality="fast", modalities=("rgb",)):
    return {"model_spec": spec, "cfg": {"render": {"quality": quality}}, "modalities": list(modalities)}


# --------------------------------------------------------------------------- the store
def test_location_from_the_environment_and_an_unusable_one_disables_caching(tmp_path, monkeypatch):
    monkeypatch.setenv("ORBITSYNTH_CACHE_DIR", str(tmp_path / "a" / "b"))
    assert D.cache_dir() == str(tmp_path / "a" / "b") and os.path.isdir(tmp_path / "a" / "b")
    monkeypatch.setenv("ORBITSYNTH_CACHE_DIR", "")
    assert D.cache_dir() is None and D.entry_path("x", b"k" * 32) is None
    (tmp_path / "file").write_text("not a folder")
    monkeypatch.setenv("ORBITSYNTH_CACHE_DIR", str(tmp_path / "file" / "sub"))
    assert D.cache_dir() is None  # no error: the cache is off
    monkeypatch.delenv("ORBITSYNTH_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setattr(D.sys, "platform", "linux")
    monkeypatch.setattr(D.os, "name", "posix")
    assert D.cache_dir() == str(tmp_path / "xdg" / "orbitsynth")


def test_an_entry_reads_back_only_whole_intact_and_under_its_own_key(tmp_path):
    key, other = D.key_digest("t", b"one"), D.key_digest("t", b"two")
    assert key != other and key != D.key_digest("u", b"one") and len(key) == 32
    path = D.entry_path("t", key, str(tmp_path))
    payload = os.urandom(100_000)
    assert D.write(path, key, payload)
    assert D.read(path, key) == payload and D.read(path) == payload and D.present(path, key)
    assert bytes(D.read_mapped(path, key)) == payload and D.read_mapped(path, other) is None
    assert D.read(path, other) is None and not D.present(path, other)
    entry = Path(path)
    data = bytearray(entry.read_bytes())
    data[-5000] ^= 0x40  # one bit of the payload
    entry.write_bytes(bytes(data))
    assert D.present(path, key) and D.read(path, key) is None  # the length is right, the checksum not
    assert D.read_mapped(path, key) is None
    entry.write_bytes(bytes(data[:-1]))
    assert not D.present(path, key) and D.read(path, key) is None and D.read_mapped(path, key) is None  # truncated
    entry.write_bytes(payload)
    assert not D.present(path, key) and D.read(path, key) is None and D.read_mapped(path) is None  # not ours
    assert D.read(str(tmp_path / "missing.bin"), key) is None
    assert [p.name for p in tmp_path.iterdir()] == [os.path.basename(path)]  # no temporary left behind


def test_concurrent_writers_leave_one_whole_entry(tmp_path):
    key = D.key_digest("c", b"same")
    path = D.entry_path("c", key, str(tmp_path))
    payloads = [bytes([k]) * 3_000_000 for k in range(6)]
    threads = [threading.Thread(target=D.write, args=(path, key, p)) for p in payloads]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert D.read(path, key) in payloads
    assert os.listdir(tmp_path) == [os.path.basename(path)]


def test_the_least_recently_used_entries_beyond_keep_are_dropped(tmp_path):
    paths = []
    for k in range(D.KEEP + 3):
        key = D.key_digest("e", str(k).encode())
        paths.append(D.entry_path("e", key, str(tmp_path)))
        assert D.write(paths[-1], key, b"x")
        os.utime(paths[-1], (1e9 + k, 1e9 + k))
    other = D.entry_path("f", D.key_digest("f", b"0"), str(tmp_path))
    D.write(other, D.key_digest("f", b"0"), b"y")
    kept = sorted(p.name for p in tmp_path.iterdir())
    assert kept == sorted([os.path.basename(p) for p in paths[-D.KEEP:]] + [os.path.basename(other)])


def test_an_unwritable_entry_is_no_error(tmp_path):
    assert not D.write(str(tmp_path / "no" / "such" / "t-00.bin"), b"k" * 32, b"payload")
    assert not D.write_stream(str(tmp_path / "no" / "such" / "t-00.bin"), b"k" * 32, lambda fh: fh.write(b"x"))


def test_a_streamed_entry_is_the_pickle_written_whole_and_a_failed_one_leaves_nothing(tmp_path):
    """``write_stream`` (a scene pickled straight to its file, never whole in memory): the entry
    reads back as ``pickle.dumps`` of the object, arrays written from their buffers included;
    a ``dump`` that raises leaves no entry and no temporary file, and raises."""
    import pickle
    obj = {"a": np.arange(300_000, dtype=np.float64), "b": np.ones((700, 3), np.float32)[::2], "c": "text"}
    key = D.key_digest("s", b"obj")
    path = D.entry_path("s", key, str(tmp_path))
    assert D.write_stream(path, key, lambda fh: pickle.dump(obj, fh, protocol=pickle.HIGHEST_PROTOCOL))
    back = pickle.loads(D.read_mapped(path, key))
    assert back.keys() == obj.keys() and back["c"] == "text"
    assert all(np.array_equal(back[k], obj[k]) and back[k].dtype == obj[k].dtype for k in ("a", "b"))
    assert D.read(path, key) == pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    # a dump that fails half-way: the old entry stays, nothing else is left
    other = D.entry_path("s", D.key_digest("s", b"broken"), str(tmp_path))

    def broken(fh):
        fh.write(b"half of a payload")
        raise pickle.PicklingError("cannot pickle this")
    with pytest.raises(pickle.PicklingError):
        D.write_stream(other, D.key_digest("s", b"broken"), broken)
    assert [p.name for p in tmp_path.iterdir()] == [os.path.basename(path)]


def test_arrays_stored_out_of_band_load_onto_the_mapped_file_aligned_and_copy_on_write(tmp_path):
    """``dump_buffers`` / ``load_buffers`` (a scene's arrays stored beside its pickle): every array
    comes back equal, with its dtype, shape and memory order (C, Fortran, strided, empty, a
    sparse matrix's); the contiguous ones are not copies but views of the mapped file, each at a
    multiple of ALIGN bytes in memory, and writable; a write changes this process's pages only,
    not the file (its checksum still holds)."""
    import scipy.sparse as sp
    rng = np.random.default_rng(3)
    obj = {"c": rng.random((301, 7)), "f": np.asfortranarray(rng.random((5, 9)).astype(np.float32)),
           "strided": np.arange(40, dtype=np.int64)[::3], "empty": np.empty((0, 3), np.int32),
           "odd": np.arange(13, dtype=np.uint8), "csr": sp.random(50, 40, density=0.1, format="csr", random_state=1),
           "text": "kept in band"}
    key = D.key_digest("s", b"oob")
    path = D.entry_path("s", key, str(tmp_path))
    assert D.write_stream(path, key, lambda fh: D.dump_buffers(obj, fh))
    view = D.read_mapped(path, key)
    back = D.load_buffers(view)
    assert back["text"] == "kept in band" and (back["csr"] != obj["csr"]).nnz == 0
    for k in ("c", "f", "strided", "empty", "odd"):
        assert back[k].dtype == obj[k].dtype and back[k].shape == obj[k].shape and np.array_equal(back[k], obj[k])
    assert back["f"].flags.f_contiguous and not back["f"].flags.c_contiguous
    lo = np.frombuffer(view, np.uint8).ctypes.data
    for a in (back["c"], back["f"], back["odd"], back["csr"].data, back["csr"].indices):
        assert not a.flags.owndata and lo <= a.ctypes.data < lo + len(view)  # on the mapping, not a copy
        assert a.ctypes.data % D.ALIGN == 0 and a.flags.writeable
    before = Path(path).read_bytes()
    back["c"][:] = -1.0
    assert Path(path).read_bytes() == before and D.read(path, key) is not None
    # a table that points outside the payload is refused, not read
    bad = bytearray(view)
    n_stream = int.from_bytes(bad[:8], "little")
    bad[16 + n_stream:24 + n_stream] = (len(bad) + 8).to_bytes(8, "little")  # buffer 0's offset
    with pytest.raises(ValueError, match="outside the payload"):
        D.load_buffers(memoryview(bytes(bad)))


# --------------------------------------------------------------------------- what is cached
def test_the_split_sum_table_from_the_cache_is_the_computed_one(tmp_path, monkeypatch):
    from raytrace import brdf
    direct = brdf._split_sum(brdf._MU_BINS, brdf._MU_BINS, brdf._SPLIT_SUM_SAMPLES, 0, brdf._MU_BINS)  # no cache
    brdf.split_sum_table.cache_clear()
    try:
        first = brdf.split_sum_table()  # computed and stored (this test's own cache folder)
        assert len([n for n in os.listdir(D.cache_dir()) if n.startswith("splitsum-")]) == 1
        brdf.split_sum_table.cache_clear()
        monkeypatch.setattr(brdf, "_split_sum", lambda *a: pytest.fail("computed again"))
        loaded = brdf.split_sum_table()
    finally:
        brdf.split_sum_table.cache_clear()
    assert np.array_equal(first, direct) and np.array_equal(loaded, direct)
    assert loaded.dtype == np.float64 and loaded.flags.writeable and loaded.flags.c_contiguous


def test_the_scene_key_follows_the_content_not_the_object(tmp_path):
    from raytrace.presets import preset_cache_options, quality_preset
    path = tmp_path / "box.obj"
    a = scenes.scene_of(scenes.load_model(_box_obj(path)), warn_model=False)
    b = scenes.scene_of(scenes.load_model(_box_obj(path)), warn_model=False)  # the same box, read again
    c = scenes.scene_of(scenes.load_model(_box_obj(path, (2.0, 1.0, 1.001))), warn_model=False)
    fast = preset_cache_options(quality_preset("fast", None), a.scale_m)
    fine = preset_cache_options(quality_preset("balanced", 16), a.scale_m)
    assert fast != fine
    keys = [scenes.scene_key(a, fast), scenes.scene_key(b, fast), scenes.scene_key(c, fast), scenes.scene_key(a, fine)]
    assert keys[0] == keys[1] and len(set(keys)) == 3


def test_a_stored_scene_is_used_by_the_next_run_and_a_broken_one_is_built_again(tmp_path, monkeypatch, capsys):
    spec = _box_obj(tmp_path / "box.obj")
    first = scenes.prebuild_scenes([_task(spec)], str(tmp_path / "tmp"))
    path = first[spec]
    assert os.path.dirname(path) == D.cache_dir()  # the persistent cache, not the temporary folder
    built = scenes.load_prebuilt(path)
    assert built is not None and len(built._caches) == 1
    from raytrace.scene import Scene
    real = Scene.radiance_cache

    def no_build(self, **options):
        pytest.fail("the radiance cache was built again")

    monkeypatch.setattr(Scene, "radiance_cache", no_build)
    assert scenes.prebuild_scenes([_task(spec)], str(tmp_path / "tmp")) == first
    # the loaded arrays lie on the mapped file: copied before the file is corrupted in place below
    key_a, ca = next(iter(built._caches.items()))
    arrays_a = {k: v.copy() for k, v in vars(ca).items() if isinstance(v, np.ndarray)}
    data = bytearray(Path(path).read_bytes())
    data[len(data) // 2] ^= 1
    Path(path).write_bytes(bytes(data))
    assert scenes.load_prebuilt(path) is None and "building the scene in the worker" in capsys.readouterr().err
    assert not os.path.exists(path)  # dropped: the next run stores it anew
    monkeypatch.setattr(Scene, "radiance_cache", real)
    assert scenes.prebuild_scenes([_task(spec)], str(tmp_path / "tmp")) == first
    again = scenes.load_prebuilt(path)
    key_b, cb = next(iter(again._caches.items()))
    assert key_a == key_b and arrays_a and all(np.array_equal(v, getattr(cb, k)) for k, v in arrays_a.items())


def test_without_a_cache_the_scene_goes_to_the_temporary_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("ORBITSYNTH_CACHE_DIR", "")
    spec = _box_obj(tmp_path / "box.obj")
    folder = tmp_path / "tmp"
    folder.mkdir()
    out = scenes.prebuild_scenes([_task(spec)], str(folder))
    assert os.path.dirname(out[spec]) == str(folder) and scenes.load_prebuilt(out[spec]) is not None
    # one process renders every frame: nothing stored, the scene kept for its frames
    monkeypatch.setattr(scenes, "_SCENES", {})
    assert scenes.prebuild_scenes([_task(spec)], None) == {} and spec in scenes._SCENES
    assert len(scenes._SCENES[spec]._caches) == 1


def test_small_jobs_render_in_this_process_when_its_kernels_are_compiled(monkeypatch):
    tasks = [_task(("builtin", "icesat"))] * pool.IN_PROCESS_FRAMES
    monkeypatch.setattr(pool.jit, "kernels_not_compiled", lambda quality, serial=False: [])
    assert pool.in_process(tasks, 2, "fast") and pool.in_process(tasks[:1], 2, "fast")
    assert not pool.in_process(tasks + tasks[:1], 2, "fast")
    monkeypatch.setattr(pool.jit, "kernels_not_compiled", lambda quality, serial=False: [] if serial else ["fast"])
    assert not pool.in_process(tasks, 2, "fast")  # compiling the parallel builds costs more than a pool
    assert pool.in_process(tasks, 1, "fast")


def test_a_built_in_target_from_the_cache_is_the_one_built(monkeypatch):
    from raytrace.targets import load_target
    built = load_target("icesat")
    scenes.builtin_model.cache_clear()
    try:
        stored = scenes.builtin_model("icesat")  # built (the same object) and stored
        assert stored is built and any(n.startswith("model-") for n in os.listdir(D.cache_dir()))
        scenes.builtin_model.cache_clear()
        monkeypatch.setattr("raytrace.targets.load_target", lambda name: pytest.fail("built again"))
        loaded = scenes.builtin_model("icesat")
    finally:
        scenes.builtin_model.cache_clear()
    assert loaded is not built and (loaded.name, loaded.description, loaded.metadata) == (
        built.name, built.description, built.metadata)
    for a, b in zip(loaded.components, built.components, strict=True):
        assert (a.name, a.material, a.semantic, a.mass_kg, a.crease_angle_rad, a.albedo) == (
            b.name, b.material, b.semantic, b.mass_kg, b.crease_angle_rad, b.albedo)
        assert np.array_equal(a.mesh.vertices, b.mesh.vertices) and np.array_equal(a.mesh.faces, b.mesh.faces)
        assert a.mesh.is_watertight == b.mesh.is_watertight and np.array_equal(a.mesh.bounds, b.mesh.bounds)
    fresh, cached = scenes.scene_of(built, False), scenes.scene_of(loaded, False)
    for k in ("vertices", "faces", "face_normal", "corner_normal", "two_sided", "hull_vertices"):
        assert np.array_equal(getattr(fresh, k), getattr(cached, k)), k
