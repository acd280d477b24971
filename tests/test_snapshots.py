"""Render snapshots: every built-in target × pattern, rendered small (160×120, frames 1-3 of a
5-frame sequence, clean RGB, paper D4 and physical degradation, mask, depth, normals) through
the pipeline's own ``plan_sequence``/``render_frame_images``, against the references committed
in tests/snapshots/. Masks must match exactly (but for ties between touching parts, which
Embree decides by the CPU's vector width), depth and normals within tight tolerances, RGB by
PSNR >= 45 dB (per frame and over the target's window; the degraded images when their input is
the reference's bit for bit, and the degradation chain on the stored inputs). A failure names
the snapshot, the modality and the metric, and writes a diff image under pytest's temporary
folder.

Updating the references is deliberate: ``python cli.py snapshots --update`` (never automatic).
The second half tests the comparison itself: a deliberately changed pixel must fail.
"""

import shutil
from pathlib import Path

import numpy as np
import pytest

import cli
from raytrace import files as F
from raytrace.dataset import snapshots as S

SNAPS = Path(cli.SNAPSHOT_DIR)
CASES = cli.snapshot_cases()
SMALL_TARGET = "icesat_spiral"  # a snapshot whose target window is small enough for a one-pixel RGB check


def test_every_target_and_pattern_has_small_references():
    assert len(CASES) == 16
    files = sorted(p.name for p in SNAPS.iterdir() if p.is_file())
    want = sorted([f"{c}.{k}" for c in CASES for k in ("rgb.webp", "rgb_paper.webp", "rgb_physical.webp",
                                                      "mask.png", "geometry.npz")] + ["settings.json"])
    assert files == want
    total = sum(p.stat().st_size for p in SNAPS.iterdir())
    assert total < 5_000_000, f"references take {total / 1e6:.2f} MB, the budget is 5 MB"
    assert S.snapshot_settings_message(str(SNAPS)) is None
    ref = S.read_snapshot(str(SNAPS), CASES[0])
    w = S.SNAPSHOT_SETTINGS["width"] * len(S.SNAPSHOT_SETTINGS["kept_frames"])
    h = S.SNAPSHOT_SETTINGS["height"]
    assert ref["rgb"].shape == ref["rgb_paper"].shape == ref["rgb_physical"].shape == (h, w, 3)
    assert ref["rgb"].dtype == np.uint8 and ref["mask"].dtype == np.uint16 and ref["mask"].shape == (h, w)
    assert ref["depth"].dtype == np.float32 and ref["normal"].dtype == np.float32 and ref["normal"].shape == (h, w, 3)
    assert ref["radiance"].dtype == np.float32 and ref["radiance"].shape == (h, w, 3)


def test_references_round_trip_bit_for_bit(tmp_path):
    rng = np.random.default_rng(1)
    h, w = 6, 15
    depth = rng.uniform(0.5, 300.0, (h, w)).astype(np.float32)
    depth[0, :3] = [np.inf, 1e-40, 0.0]  # miss, subnormal, zero
    normal = rng.normal(size=(h, w, 3)).astype(np.float32)
    normal[1, 1] = [-0.0, 0.0, -1.0]
    images = {"rgb": rng.integers(0, 256, (h, w, 3), dtype=np.uint8), "mask": rng.integers(0, 65536, (h, w),
                                                                                        dtype=np.uint16),
              "rgb_paper": rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
              "rgb_physical": rng.integers(0, 256, (h, w, 3), dtype=np.uint8), "depth": depth, "normal": normal,
              "radiance": rng.lognormal(0.0, 3.0, (h, w, 3)).astype(np.float32)}
    S.write_snapshot(str(tmp_path), "x", images)
    back = S.read_snapshot(str(tmp_path), "x")
    for m, a in images.items():
        assert back[m].dtype == a.dtype and back[m].shape == a.shape, m
        assert back[m].tobytes() == a.tobytes(), m  # bit for bit: lossless WebP, PNG, float32 byte planes
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]


@pytest.mark.parametrize("name", CASES)
def test_render_matches_reference(name, tmp_path_factory):
    new = cli.render_snapshot(name)
    ref = S.read_snapshot(str(SNAPS), name)
    assert (ref["mask"] > 0).any(), f"{name}: the reference shows no target; the snapshot would guard nothing"
    diff_dir = tmp_path_factory.mktemp(f"snapshot-diff-{name}")
    msgs = S.compare_snapshot(name, ref, new, diff_dir=str(diff_dir))
    msgs += S.check_snapshot_degradation(name, ref, cli.degrade_snapshot(name, ref), diff_dir=str(diff_dir))
    assert not msgs, ("render snapshots moved (if intended: python cli.py snapshots --update):\n"
                      + "\n".join(msgs))


# --------------------------------------------------------------------------- the comparison itself
@pytest.fixture(scope="module")
def ref():
    return S.read_snapshot(str(SNAPS), SMALL_TARGET)


def _copy(images: dict) -> dict:
    return {k: v.copy() for k, v in images.items()}


def _target_pixel(ref: dict) -> tuple:
    ys, xs = np.nonzero(ref["mask"] > 0)
    return int(ys[len(ys) // 2]), int(xs[len(xs) // 2])


def test_identical_snapshot_passes(ref, tmp_path):
    assert S.compare_snapshot(SMALL_TARGET, ref, _copy(ref), diff_dir=str(tmp_path)) == []
    assert not any(tmp_path.iterdir())


def test_one_changed_mask_pixel_fails_with_a_diff_image(ref, tmp_path):
    new = _copy(ref)
    y, x = _target_pixel(ref)
    new["mask"][y, x] = 0
    msgs = S.compare_snapshot(SMALL_TARGET, ref, new, diff_dir=str(tmp_path))
    assert len(msgs) == 1 and msgs[0].startswith(f"{SMALL_TARGET}: mask: 1 of {ref['mask'].size} pixels")
    path = tmp_path / f"{SMALL_TARGET}.mask.diff.png"
    assert str(path) in msgs[0]
    diff = F.read_image(str(path))
    h, w = ref["mask"].shape
    assert diff.shape == (2 * 3 * h, 2 * w, 3)  # reference, candidate, failures; twice the size
    assert tuple(diff[2 * (2 * h + y), 2 * x]) == (255, 0, 0)  # the changed pixel is red in the failure row
    assert np.count_nonzero(np.all(diff[4 * h:] == (255, 0, 0), axis=-1)) == 4


@pytest.mark.parametrize("modality", ["rgb", "rgb_paper", "rgb_physical"])
def test_one_changed_rgb_pixel_on_the_target_fails(ref, tmp_path, modality):
    new = _copy(ref)
    y, x = _target_pixel(ref)
    new[modality][y, x] = np.where(ref[modality][y, x] > 127, 0, 255)  # a large change of one pixel
    msgs = S.compare_snapshot(SMALL_TARGET, ref, new, diff_dir=str(tmp_path))
    assert len(msgs) == 1 and msgs[0].startswith(f"{SMALL_TARGET}: {modality}: PSNR ")
    assert "target window" in msgs[0] and "1 pixels differ" in msgs[0]
    assert (tmp_path / f"{SMALL_TARGET}.{modality}.diff.png").is_file()


def test_a_dimmer_image_fails_and_one_dn_of_noise_passes(ref, tmp_path):
    dim = _copy(ref)
    dim["rgb"] = (ref["rgb"] * 0.9).astype(np.uint8)  # e.g. a changed exposure or BRDF
    msgs = S.compare_snapshot(SMALL_TARGET, ref, dim, diff_dir=str(tmp_path))
    assert len(msgs) == 1 and "rgb: PSNR" in msgs[0]
    noisy = _copy(ref)  # what float noise across machines may do: 1 DN on some pixels
    rng = np.random.default_rng(0)
    flip = rng.random(ref["rgb"].shape) < 0.2
    noisy["rgb"] = np.where(flip & (ref["rgb"] < 255), ref["rgb"] + 1, ref["rgb"]).astype(np.uint8)
    assert S.compare_snapshot(SMALL_TARGET, ref, noisy, diff_dir=str(tmp_path)) == []


def test_depth_and_normals_fail_on_one_pixel_and_absorb_float_noise(ref, tmp_path):
    y, x = _target_pixel(ref)
    for change, name in ((lambda n: n["depth"].__setitem__((y, x), n["depth"][y, x] + np.float32(0.002)), "depth"),
                         (lambda n: n["depth"].__setitem__((y, x), np.inf), "depth"),
                         (lambda n: n["normal"].__setitem__((y, x), -n["normal"][y, x]), "normal"),
                         (lambda n: n["normal"].__setitem__((y, x, 0), n["normal"][y, x, 0] + np.float32(1e-3)),
                          "normal")):
        new = _copy(ref)
        change(new)
        msgs = S.compare_snapshot(SMALL_TARGET, ref, new, diff_dir=str(tmp_path))
        assert len(msgs) == 1 and msgs[0].startswith(f"{SMALL_TARGET}: {name}: 1 pixels"), msgs
    new = _copy(ref)
    hit = np.isfinite(ref["depth"])
    new["depth"][hit] *= np.float32(1 + 2e-6)  # far below 1e-4 m + 1e-5 depth
    new["normal"] += np.float32(1e-6) * (ref["normal"] != 0)
    assert S.compare_snapshot(SMALL_TARGET, ref, new, diff_dir=str(tmp_path)) == []


def test_other_shapes_or_settings_are_reported_as_stale(ref, tmp_path, monkeypatch):
    new = _copy(ref)
    new["rgb"] = new["rgb"][:, :-1]
    msgs = S.compare_snapshot(SMALL_TARGET, ref, new, diff_dir=str(tmp_path))
    assert msgs and "snapshot settings changed" in msgs[0] and "--update" in msgs[0]
    monkeypatch.setitem(S.SNAPSHOT_SETTINGS, "quality", "balanced")
    msg = S.snapshot_settings_message(str(SNAPS))
    assert msg is not None and "stale" in msg and "--update" in msg


def test_snapshots_command_fails_on_a_changed_reference_and_update_restores_it(tmp_path, capsys):
    refs = tmp_path / "refs"
    refs.mkdir()
    for p in SNAPS.glob(f"{SMALL_TARGET}.*"):
        shutil.copy(p, refs / p.name)
    shutil.copy(SNAPS / "settings.json", refs / "settings.json")
    mask = F.read_image(str(refs / f"{SMALL_TARGET}.mask.png"))
    y, x = _target_pixel({"mask": mask})
    mask[y, x] += 1
    F.write_image(str(refs / f"{SMALL_TARGET}.mask.png"), mask)
    target, pattern = SMALL_TARGET.split("_")
    argv = ["snapshots", "--targets", target, "--patterns", pattern, "--dir", str(refs),
            "--diff-dir", str(tmp_path / "diffs")]
    assert cli.main(argv) == 1
    out = capsys.readouterr().out
    assert f"FAIL {SMALL_TARGET}: mask: 1 of" in out and str(tmp_path / "diffs") in out and "--update" in out
    assert (tmp_path / "diffs" / f"{SMALL_TARGET}.mask.diff.png").is_file()
    # --update rewrites the reference with this machine's render, which is reproducible: it equals
    # a second render written apart pixel for pixel and value for value, and the committed
    # reference within the check's own tolerances on any machine (bit for bit on the machine that
    # wrote the committed snapshots; another CPU's SIMD width can move a float rounding, an Embree
    # tie, and with them a few 8-bit values: seen on an AVX-512 machine against AVX2 snapshots).
    # The files' bytes also depend on the encoders' versions: zlib, libwebp, and CPython's
    # zipfile, which marks numpy's .npz entries ZIP64-version only from 3.11.4.
    assert cli.main(argv[:-2] + ["--update"]) == 0
    assert "review them" in capsys.readouterr().out
    assert sorted(p.name for p in refs.iterdir()) == sorted(p.name for p in SNAPS.glob(f"{SMALL_TARGET}.*")) + [
        "settings.json"]
    new, old = S.read_snapshot(str(refs), SMALL_TARGET), S.read_snapshot(str(SNAPS), SMALL_TARGET)
    assert new.keys() == old.keys()
    again = tmp_path / "again"
    again.mkdir()
    S.write_snapshot(str(again), SMALL_TARGET, cli.render_snapshot(SMALL_TARGET))
    again = S.read_snapshot(str(again), SMALL_TARGET)
    assert new.keys() == again.keys()
    for key in new:
        assert new[key].dtype == again[key].dtype and np.array_equal(new[key], again[key]), key
        assert new[key].dtype == old[key].dtype and new[key].shape == old[key].shape, key
    assert S.compare_snapshot(SMALL_TARGET, old, new, diff_dir=str(tmp_path / "diffs2")) == []
    assert (refs / "settings.json").read_bytes() == (SNAPS / "settings.json").read_bytes()
    assert cli.main(argv) == 0
    assert "1 snapshots match" in capsys.readouterr().out


def test_snapshots_command_errors_are_one_line(tmp_path, capsys):
    assert cli.main(["snapshots", "--targets", "icesat", "--patterns", "spiral", "--dir", str(tmp_path)]) == 1
    assert "missing" in capsys.readouterr().out  # no settings.json: stale, says how to write references
    with pytest.raises(SystemExit) as exc:
        cli.main(["snapshots", "--targets", "hubble"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--targets" in err and "tiangong" in err


def test_snapshots_command_checks_its_folders_before_rendering(tmp_path, monkeypatch, capsys):
    """A --dir that is not a folder, or a --diff-dir / --update --dir that cannot be written, is one line on
    stderr naming that option, exit 2, before any render (they failed after the renders: exit 1 on stdout,
    or --diff-dir blamed on --dir with a raw errno)."""
    monkeypatch.setattr(cli, "render_snapshot", lambda name: pytest.fail("rendered before checking the folders"))
    afile = tmp_path / "afile"
    afile.write_text("x")
    base = ["snapshots", "--targets", "icesat", "--patterns", "spiral"]
    for extra, option in ((["--dir", str(tmp_path / "nowhere")], "--dir"), (["--dir", str(afile)], "--dir"),
                          (["--update", "--dir", str(afile / "refs")], "--dir"),
                          (["--diff-dir", str(afile)], "--diff-dir")):
        assert cli.main([*base, *extra]) == 2, extra
        cap = capsys.readouterr()
        assert cap.out == "" and cap.err.count("\n") == 1 and f"error: {option}" in cap.err, (extra, cap)


def test_snapshots_command_leaves_no_empty_temporary_folder(tmp_path, monkeypatch, capsys):
    # without --diff-dir the diff images go to a new temporary folder; it must not stay behind
    # empty when there is nothing to show (stale references, --update, all matching)
    import tempfile
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    target, pattern = SMALL_TARGET.split("_")
    refs = tmp_path / "refs"
    refs.mkdir()
    argv = ["snapshots", "--targets", target, "--patterns", pattern, "--dir", str(refs)]
    assert cli.main(argv) == 1  # no references yet: stale
    assert list(tmp.iterdir()) == []
    assert cli.main(argv + ["--update"]) == 0
    assert list(tmp.iterdir()) == []
    assert cli.main(argv) == 0
    assert list(tmp.iterdir()) == []
    mask = F.read_image(str(refs / f"{SMALL_TARGET}.mask.png"))
    y, x = _target_pixel({"mask": mask})
    mask[y, x] += 1
    F.write_image(str(refs / f"{SMALL_TARGET}.mask.png"), mask)
    assert cli.main(argv) == 1  # a failure keeps its diff image
    (kept,) = tmp.iterdir()
    assert (kept / f"{SMALL_TARGET}.mask.diff.png").is_file()
    assert str(kept) in capsys.readouterr().out


def _boundary(m: np.ndarray) -> np.ndarray:
    """Pixels whose right-hand neighbour shows another part (both hit) and whose left-hand
    neighbour their own: swapping such a pixel's id for its right-hand neighbour's leaves its
    own id beside it, as a tie between touching parts would."""
    out = np.zeros(m.shape, dtype=bool)
    out[:, 1:-1] = (m[:, 1:-1] > 0) & (m[:, 2:] > 0) & (m[:, 1:-1] != m[:, 2:]) & (m[:, :-2] == m[:, 1:-1])
    return out


def _part_boundary_pixel(ref: dict) -> tuple:
    """A pixel on the target whose right-hand neighbour shows another part (:func:`_boundary`)."""
    ys, xs = np.nonzero(_boundary(ref["mask"].astype(np.int64)))
    assert len(ys), "the reference shows no boundary between two parts"
    return int(ys[0]), int(xs[0])


def test_a_tie_between_touching_parts_passes_and_other_id_changes_fail(ref, tmp_path):
    y, x = _part_boundary_pixel(ref)
    other = ref["mask"][y, x + 1]
    tie = _copy(ref)  # the neighbouring part reported at the same distance: another CPU's tie
    tie["mask"][y, x] = other
    assert S.compare_snapshot(SMALL_TARGET, ref, tie, diff_dir=str(tmp_path)) == []
    deeper = _copy(tie)  # the same id change, but the hit moved: not a tie
    deeper["depth"][y, x] += np.float32(0.01)
    msgs = S.compare_snapshot(SMALL_TARGET, ref, deeper, diff_dir=str(tmp_path))
    assert [m.split(":")[1].strip() for m in msgs] == ["mask", "depth"]
    assert msgs[0].startswith(f"{SMALL_TARGET}: mask: 1 of")
    far = _copy(ref)  # an id that no neighbour has
    far["mask"][y, x] = int(ref["mask"].max()) + 1
    msgs = S.compare_snapshot(SMALL_TARGET, ref, far, diff_dir=str(tmp_path))
    assert len(msgs) == 1 and msgs[0].startswith(f"{SMALL_TARGET}: mask: 1 of")


def test_more_ties_than_the_bound_all_fail(ref, tmp_path):
    m = ref["mask"].astype(np.int64)
    boundary = _boundary(m)  # pixels whose right-hand neighbour is another part
    n_target = np.count_nonzero(m > 0)
    need = int(S.SNAPSHOT_MASK_TIES * n_target) + 1
    ys, xs = np.nonzero(boundary)
    if len(ys) < need:
        pytest.skip(f"{SMALL_TARGET} has only {len(ys)} part-boundary pixels, {need} needed")
    new = _copy(ref)
    new["mask"][ys[:need], xs[:need]] = ref["mask"][ys[:need], xs[:need] + 1]
    msgs = S.compare_snapshot(SMALL_TARGET, ref, new, diff_dir=str(tmp_path))
    assert len(msgs) == 1 and msgs[0].startswith(f"{SMALL_TARGET}: mask: {need} of")


def test_degraded_images_are_compared_only_with_the_same_input(ref, tmp_path):
    moved = _copy(ref)  # the clean image moved by 1 DN (another CPU), so the paper noise is another draw
    y, x = _target_pixel(ref)
    moved["rgb"][y, x] = np.where(ref["rgb"][y, x] < 255, ref["rgb"][y, x] + 1, 254)
    moved["rgb_paper"] = np.random.default_rng(5).integers(0, 256, ref["rgb_paper"].shape, dtype=np.uint8)
    assert S.compare_snapshot(SMALL_TARGET, ref, moved, diff_dir=str(tmp_path)) == []
    moved = _copy(ref)  # the radiance moved in its last bit: the physical noise is another draw
    moved["radiance"][y, x, 0] = np.nextafter(ref["radiance"][y, x, 0], np.float32(np.inf))
    moved["rgb_physical"] = 255 - ref["rgb_physical"]
    assert S.compare_snapshot(SMALL_TARGET, ref, moved, diff_dir=str(tmp_path)) == []
    moved["rgb_paper"] = 255 - ref["rgb_paper"]  # its own input (the clean RGB) did not move: compared
    msgs = S.compare_snapshot(SMALL_TARGET, ref, moved, diff_dir=str(tmp_path))
    assert len(msgs) == 1 and msgs[0].startswith(f"{SMALL_TARGET}: rgb_paper: PSNR ")


def test_the_chain_reproduces_the_stored_degraded_images_and_catches_a_change(ref, tmp_path):
    again = cli.degrade_snapshot(SMALL_TARGET, ref)
    assert S.check_snapshot_degradation(SMALL_TARGET, ref, again, diff_dir=str(tmp_path)) == []
    for modality in ("rgb_paper", "rgb_physical"):
        changed = _copy(ref)
        y, x = _target_pixel(ref)
        changed[modality][y, x] = np.where(ref[modality][y, x] > 127, 0, 255)
        again = cli.degrade_snapshot(SMALL_TARGET, changed)
        msgs = S.check_snapshot_degradation(SMALL_TARGET, changed, again, diff_dir=str(tmp_path))
        assert len(msgs) == 1 and msgs[0].startswith(f"{SMALL_TARGET}: {modality}: degrading the reference's own "
                                                     "input: PSNR "), msgs
        assert (tmp_path / f"{SMALL_TARGET}.{modality}.diff.png").is_file()
    dimmer = _copy(ref)  # a chain that sees another input gives other degraded images
    dimmer["radiance"] = ref["radiance"] * np.float32(0.8)
    again = cli.degrade_snapshot(SMALL_TARGET, dimmer)
    msgs = S.check_snapshot_degradation(SMALL_TARGET, dimmer, again, diff_dir=str(tmp_path))
    assert [m.split(":")[1].strip() for m in msgs] == ["rgb_physical"]
