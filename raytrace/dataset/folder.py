"""The sequence folder: its format, its claim by one run, resume, and completion.

A sequence folder holds ``scenario.json`` (the configuration and the plan, written first: it
identifies the sequence), ``camera.json``, ``config.toml``, the target's ``model/`` (mesh and
keypoints), one folder per modality (:mod:`.modalities`) with a file per frame, a manifest
record per complete frame (``.manifest/NNNNNN.json``, with checksums) and, once every frame is complete,
``labels.json`` and ``manifest.json``. A run claims the folder (its lock), skips the frames
already complete, writes each frame's files under temporary names and renames them, and
removes what it leaves incomplete. docs/formats.md gives every file; docs/cli.md the rules.

A *plan* is the dict the command line makes of one sequence: ``result`` (the scenario and the
per-frame labels), ``cfg`` (the configuration), ``model``, ``model_spec``, ``camera``,
``lights``, ``name`` and ``keypoints`` (the ``model/keypoints.json`` document, optional). A
*task* is one frame of it, as :func:`tasks_for` makes it.
"""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np

from .. import files as F
from . import UsageError, warn
from .modalities import MODALITIES, relpath, write_options

def _versions() -> dict:
    import platform
    from importlib import metadata
    out = {"python": platform.python_version()}
    for dist in ("orbitsynth", "numpy", "scipy", "numba", "embreex", "trimesh", "OpenImageIO", "scikit-image"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


def camerajson_text(camera, cfg: dict) -> dict:
    K = camera.K.tolist()
    cam = cfg["camera"]
    return {"K": K, "width": camera.width, "height": camera.height,
            "fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy,
            "focal_length_m": cam["focal_length_mm"] * 1e-3, "pixel_pitch_m": cam["pixel_pitch_um"] * 1e-6,
            "convention": "OpenCV: x right, y down, z forward; integer pixel coordinates are pixel centres",
            # SPEED+-style keys
            "cameraMatrix": K, "distCoeffs": list(camera.dist_coeffs), "Nu": camera.width, "Nv": camera.height,
            "ppx": cam["pixel_pitch_um"] * 1e-6, "ppy": cam["pixel_pitch_um"] * 1e-6}


def frames_to_write(plan: dict) -> list:
    frames = plan["result"]["frames"]
    only = plan["cfg"]["output"]["only_visible"]
    return [f["frame"] for f in frames if f["visible"] or not only]


def scenario_doc(plan: dict) -> dict:
    """The ``scenario.json`` document of a plan: the configuration, the versions, the plan's
    scenario fields (its frames aside) and how the images were exposed and seeded."""
    res, cfg, model = plan["result"], plan["cfg"], plan["model"]
    scen = {"format": SCENARIO_FORMAT, "config": cfg, "seed": cfg["sequence"]["seed"],
            "versions": _versions()}
    scen.update({k: v for k, v in res.items() if k != "frames"})
    scen["target_model"] = {
        "file": f"model/{res['target']}.ply",
        "n_triangles": model.n_triangles,
        "components": [{"id": k + 1, "name": c.name, "material": c.material, "semantic": c.semantic}
                       for k, c in enumerate(model.components)]}
    if plan.get("keypoints") is not None:  # the points by their file's digest: other points, another sequence
        kp = plan["keypoints"]
        scen["target_model"]["keypoints"] = {
            "file": KEYPOINTS_FILE, "count": len(kp["names"]), "source": kp["source"],
            "sha256": hashlib.sha256(json_text(kp).encode("utf-8")).hexdigest()}
    scen["visible"] = [f["visible"] for f in res["frames"]]
    scen["frames_written"] = frames_to_write(plan)
    scen["exposure"] = ("fixed: linear = radiance * pi / 1361 W/m2 (a white Lambertian surface facing the Sun "
                        "is 1.0), sRGB 8-bit" if cfg["render"]["exposure"] == "fixed" else
                        "auto: per frame, 99.5th luminance percentile of the target -> 0.9 (exposure_scale in labels)")
    if cfg["degrade"]["degrade"] == "physical" and cfg["degrade"]["motion_blur"] == "auto":
        scen["motion_blur"] = ("auto: per frame, a straight line along the principal axis v of the target's hull "
                               "vertices' image positions over the exposure, of length min(sqrt(12 lambda), E) "
                               "(lambda: their mean variance along v; E: the RMS of their paths' extents along v), the "
                               "largest over centred parts of the exposure, at most the image diagonal; "
                               "motion_blur_px and motion_angle_deg in labels")
    scen["random_streams"] = ("frame i: SeedSequence(seed).spawn(n)[i]; render seed = generate_state(1)[0] mod 2^31, "
                              "degradation rng = its first spawned child")
    return scen


def json_text(obj) -> str:
    return json.dumps(obj, indent=1, allow_nan=False) + "\n"


def _first_missing(path: str) -> str | None:
    path = os.path.abspath(path)
    missing = None
    while not os.path.exists(path):
        missing = path
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    return missing


def _read_bytes(path: str) -> bytes:
    with open(path, "rb") as fh:
        return fh.read()


SCENARIO_FORMAT = "orbitsynth sequence 1"
KEYPOINTS_FILE = "model/keypoints.json"
"""The sequence's keypoints (:mod:`raytrace.keypoints`), beside the model."""
_SCENARIO_LIMIT = 256 << 20  # bytes; a million frames' scenario.json is ~30 MB


def _own_entry(name: str, path: str) -> bool:
    """Whether ``name`` in a folder without ``scenario.json`` may be left by this tool: its lock
    file, a temporary file of an interrupted write, or one of its sub-folders, empty."""
    if name == F.LOCK_NAME or F.is_temporary(name):
        return True
    if name in MODALITIES or name in ("model", F.MANIFEST_DIR):
        try:
            return os.path.isdir(path) and not os.path.islink(path) and not os.listdir(path)
        except OSError:
            return False
    return False


def judge_sequence_folder(seq_dir: str, scenario: str) -> bool:
    """Decide, before anything is written, whether the main job may write the sequence whose
    ``scenario.json`` text is ``scenario`` into ``seq_dir``: True if the folder holds that very
    sequence (it is resumed), False if it is missing or empty (or holds only this tool's
    leftovers of an interrupted start).

    Raises
    ------
    UsageError
        The path is not a writable folder; the folder holds another sequence, a
        ``scenario.json`` that is not one of this tool's, or other files.
    """
    if not os.path.lexists(seq_dir):
        return False
    if not os.path.isdir(seq_dir):
        raise UsageError(f"--out: {seq_dir} exists and is not a folder")
    if not os.access(seq_dir, os.W_OK | os.X_OK):
        raise UsageError(f"--out: {seq_dir} is not writable")
    scen_path = os.path.join(seq_dir, "scenario.json")
    foreign = f"--out: {seq_dir} holds something that is not a sequence of this tool"
    if os.path.lexists(scen_path):
        try:
            data = F.read_regular_file(scen_path, limit_bytes=_SCENARIO_LIMIT, what="scenario.json")
        except ValueError as exc:
            raise UsageError(f"{foreign} ({exc}); choose another --out") from None
        try:
            doc = json.loads(data.decode("utf-8"))
        except ValueError:  # UnicodeDecodeError too
            doc = None
        if not isinstance(doc, dict) or doc.get("format") != SCENARIO_FORMAT:
            raise UsageError(f"{foreign} (its scenario.json is not an orbitsynth scenario); choose another --out")
        if data.decode("utf-8") != scenario:
            raise UsageError(f"--out: {seq_dir} holds another sequence (its scenario.json differs from these "
                           "options); choose another --out or delete it")
        return True
    try:
        names = sorted(os.listdir(seq_dir))
    except OSError as exc:
        raise UsageError(f"--out: cannot read {seq_dir} ({exc.strerror or exc})") from None
    other = [n for n in names if not _own_entry(n, os.path.join(seq_dir, n))]
    if other:
        shown = ", ".join(other[:3]) + (f" and {len(other) - 3} more" if len(other) > 3 else "")
        raise UsageError(f"--out: {seq_dir} is not empty and holds no sequence of this tool ({shown}); give a new or "
                       "empty folder, or a sequence folder this tool wrote")
    return False


class SequenceClaim:
    """A sequence folder this run writes into: its lock (:class:`raytrace.files.FolderLock`,
    held until :meth:`release`) and what this run created in preparing it, which
    :meth:`undo` removes when the run is refused or fails before any frame."""

    def __init__(self, seq_dir: str, lock, created_dir: str | None):
        self.seq_dir = seq_dir
        self.lock = lock
        self.created_dir = created_dir  # the outermost folder this run made (the sequence folder or a parent)
        self.created: list = []  # files and folders this run made inside an existing sequence folder

    def undo(self) -> None:
        """Remove what this run created, where no other run shares the folder (a shard of the
        same sequence may have started on it), and release the lock: a refused run leaves the
        folder as it found it."""
        import shutil
        alone = self.lock.fd is None or self.lock.try_exclusive()
        if alone:
            for path in reversed(self.created):
                try:
                    os.rmdir(path) if os.path.isdir(path) and not os.path.islink(path) else os.unlink(path)
                except OSError:
                    pass
        self.lock.release(remove=alone and self.lock.created)
        if alone and self.created_dir is not None:
            shutil.rmtree(self.created_dir, ignore_errors=True)

    def release(self) -> None:
        """Release the lock at the end of the run; its file goes with it where no other run
        holds it."""
        self.lock.release(remove=True)


def prepare_sequence(plan: dict, seq_dir: str, *, config_text: str, shared: bool = False) -> SequenceClaim:
    """Claim the sequence folder: judge it before writing anything
    (:func:`judge_sequence_folder`), take its lock (exclusive for a whole run, ``shared`` for a
    shard), then create ``scenario.json`` (atomically: of shards starting at once, one creates
    it and the others must find the same text), ``camera.json``, ``config.toml``, ``model/``
    and the modality folders (``config_text``: the configuration as TOML). Returns the claim; the caller releases it when the run ends.

    Raises
    ------
    UsageError
        The folder is refused (another sequence, foreign files, in use by another run, not
        writable); whatever this call created is removed first.
    """
    scenario = json_text(scenario_doc(plan))
    judge_sequence_folder(seq_dir, scenario)
    created_dir = _first_missing(seq_dir)
    try:
        os.makedirs(seq_dir, exist_ok=True)
    except OSError as exc:
        if created_dir is not None and os.path.isdir(created_dir):
            import shutil
            shutil.rmtree(created_dir, ignore_errors=True)
        raise UsageError(f"--out: cannot create {seq_dir} ({exc.strerror or exc})") from None
    lock = F.FolderLock(seq_dir, shared=shared)
    try:
        lock.acquire()
    except F.FolderLockBusy:
        # another run owns the folder now (even if this one made it a moment ago): touch nothing
        raise UsageError(f"--out: {seq_dir} is in use by another run writing into it (it holds the folder's lock "
                       f"{F.LOCK_NAME}); wait for it to end or choose another --out") from None
    except OSError as exc:
        if created_dir is not None:
            import shutil
            shutil.rmtree(created_dir, ignore_errors=True)
        raise UsageError(f"--out: cannot write into {seq_dir} ({exc.strerror or exc})") from None
    if lock.unsupported:
        warn(f"--out: {seq_dir} cannot be locked ({lock.unsupported}); another run writing into it at the same "
             "time would not be refused")
    claim = SequenceClaim(seq_dir, lock, created_dir)
    try:
        judge_sequence_folder(seq_dir, scenario)  # again, under the lock: another run may have prepared it
        F.remove_stale_temporaries(seq_dir)

        def made(path: str) -> None:
            if created_dir is None:
                claim.created.append(path)

        scen_path = os.path.join(seq_dir, "scenario.json")
        if not os.path.exists(scen_path):
            if F.create_new_text(scen_path, scenario):
                made(scen_path)
            else:  # a shard of another run created it first: it must be this sequence
                judge_sequence_folder(seq_dir, scenario)
        for rel in [*plan["cfg"]["output"]["modalities"], "model"]:
            path = os.path.join(seq_dir, rel)
            if not os.path.isdir(path):
                os.makedirs(path, exist_ok=True)
                made(path)
        scen = json.loads(scenario)
        blobs = {scen["target_model"]["file"]: F.model_ply_bytes(plan["model"]),
                 "camera.json": json_text(camerajson_text(plan["camera"], plan["cfg"])).encode("utf-8"),
                 "config.toml": config_text.encode("utf-8")}
        if plan.get("keypoints") is not None:
            blobs[KEYPOINTS_FILE] = json_text(plan["keypoints"]).encode("utf-8")
        for rel, data in blobs.items():
            path = os.path.join(seq_dir, rel)
            if not (os.path.isfile(path) and _read_bytes(path) == data):
                existed = os.path.lexists(path)
                F.atomic_write_bytes(path, data)
                if not existed:
                    made(path)
    except BaseException as exc:
        claim.undo()
        if isinstance(exc, OSError):
            raise UsageError(f"--out: cannot write into {seq_dir} ({exc.strerror or exc})") from None
        raise
    return claim


def frame_files(seq_dir: str, frame: int, modalities) -> list:
    return [os.path.join(seq_dir, relpath(m, frame)) for m in modalities]


def remove_incomplete_frames(tasks: list) -> int:
    """After a failed or interrupted run: delete the image files of this run's frames that have
    no manifest record (written before the failure; a rerun renders them again), so that no
    half-written frame stays. Returns how many files were removed."""
    removed = 0
    for task in tasks:
        if not task.get("write", True) or F.read_frame_record(task["out"], task["frame"]) is not None:
            continue
        for path in frame_files(task["out"], task["frame"], task["modalities"]):
            try:
                os.unlink(path)
                removed += 1
            except OSError:
                pass
    return removed


def finish_sequence(plan: dict, seq_dir: str, verified=frozenset()) -> dict:
    """Write labels.json and manifest.json if every frame of the sequence is complete (from
    any run or shard). Frames not in ``verified`` (those this run neither rendered nor checked
    before skipping: other shards') are checked against their records' SHA-256 first; a frame
    whose files do not match is not complete. Where the sequence is not complete, a
    labels.json and manifest.json left from an earlier state are removed: they would disagree
    with the files. Returns counts and the frames found corrupt."""
    wanted = frames_to_write(plan)
    records, corrupt = {}, []
    for i in wanted:
        rec = F.read_frame_record(seq_dir, i)
        if rec is None:
            continue
        bad = [rel for rel, digest in rec["files"].items()
               if not os.path.isfile(os.path.join(seq_dir, rel))
               or (i not in verified and F.sha256_file(os.path.join(seq_dir, rel)) != digest)]
        if bad:
            corrupt.append((i, bad[0]))
        else:
            records[i] = rec
    done = len(records) == len(wanted)
    if done:
        labels = [records[i]["label"] for i in wanted]
        files = {}
        model = scenario_doc(plan)["target_model"]
        kp_file = [model["keypoints"]["file"]] if "keypoints" in model else []
        for rel in ("scenario.json", "camera.json", "config.toml", model["file"], *kp_file):
            files[rel] = F.sha256_file(os.path.join(seq_dir, rel))
        for i in wanted:
            files.update(records[i]["files"])
        labels_text = json_text(labels)
        F.atomic_write_text(os.path.join(seq_dir, "labels.json"), labels_text)
        files["labels.json"] = F.sha256_file(os.path.join(seq_dir, "labels.json"))
        F.atomic_write_text(os.path.join(seq_dir, "manifest.json"),
                            json_text({"format": "orbitsynth manifest 1", "algorithm": "sha256", "files": files}))
    else:
        for rel in ("manifest.json", "labels.json"):
            try:
                os.unlink(os.path.join(seq_dir, rel))
            except FileNotFoundError:
                pass
    return {"complete": done, "present": len(records), "wanted": len(wanted), "corrupt": corrupt}


def tasks_for(plan: dict, seq_dir: str, shard: tuple | None, *, write: bool = True, frames=None) -> tuple:
    """(tasks to run, frames skipped as complete) for the frames of this shard."""
    cfg, cam = plan["cfg"], plan["camera"]
    wanted = frames_to_write(plan) if frames is None else list(frames)
    if shard is not None:
        k, n = shard
        wanted = [i for i in wanted if i % n == k - 1]
    tasks, skipped = [], 0
    kp_points = plan["keypoints"]["points_body_m"] if plan.get("keypoints") is not None else None
    for i in wanted:
        if write and F.frame_complete(seq_dir, i) is not None:
            skipped += 1
            continue
        label = plan["result"]["frames"][i]
        nxt = plan["result"]["frames"][i + 1] if i + 1 < len(plan["result"]["frames"]) else None
        tasks.append({"frame": i, "out": seq_dir, "write": write, "cfg": cfg, "model_spec": plan["model_spec"],
                      "camera": (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, cam.dist_coeffs),
                      "R_cam_from_body": label["R_cam_from_body"], "t_cam_m": label["t_cam_m"],
                      # the next planned frame's pose (written or not), for the flow
                      "next_pose": None if nxt is None else (nxt["R_cam_from_body"], nxt["t_cam_m"]),
                      "light": plan["lights"][i], "label": label, "keypoints_body_m": kp_points,
                      "modalities": cfg["output"]["modalities"] if write else [], "want_rgb": not write})
    return tasks, skipped


def write_files_atomically(out_dir: str, files: dict, texts: dict) -> None:
    """:func:`raytrace.files.write_files_atomically`, failures as a one-line UsageError naming --out."""
    from raytrace.files import write_files_atomically as write
    try:
        write(out_dir, files, texts)
    except OSError as exc:
        raise UsageError(f"--out: {exc}") from None


def check_out_folder(out_dir: str, option: str = "--out") -> None:
    """Fail before any work when ``option`` (``--out``) cannot become a writable folder: it exists
    and is not a folder or not writable, or its nearest existing parent is not a writable folder."""
    if not str(out_dir).strip():
        raise UsageError(f"{option} must name a folder, got an empty string")
    path = os.path.abspath(out_dir)
    if os.path.exists(path):
        if not os.path.isdir(path):
            raise UsageError(f"{option}: {out_dir} exists and is not a folder")
        if not os.access(path, os.W_OK | os.X_OK):
            raise UsageError(f"{option}: {out_dir} is not writable")
        return
    parent = os.path.dirname(path)
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent) or not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"{option}: cannot create {out_dir} ({parent} is not a writable folder)")
    # os.access says yes to root everywhere, /proc and /sys included: make (and remove) a
    # folder there to be sure before the render
    import tempfile
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".probe-", dir=parent))
    except OSError as exc:
        raise UsageError(f"{option}: cannot create {out_dir} ({parent}: {exc.strerror})") from None


SCENE_MODALITIES = ("rgb", "mask", "depth", "normal", "hdr")
"""The modalities ``render-scene`` writes (frame ``000000``)."""


def check_scene_out(out_dir: str) -> None:
    """``render-scene`` writes frame 000000's five modality files and ``frame.json`` into a new folder, a
    folder without them, or over its own earlier frame. A folder holding a sequence (its
    ``scenario.json``, ``labels.json`` or ``manifest.json``), modality folders with other files, or
    those files without a ``frame.json`` is refused before the render, so nothing of it is
    overwritten or mixed with this frame. Unrelated files beside them are left alone."""
    path = os.path.abspath(out_dir)
    if not os.path.isdir(path):
        return
    own = {relpath(d, "000000") for d in SCENE_MODALITIES}
    found, other = set(), []
    for name in ("scenario.json", "labels.json", "manifest.json"):
        if os.path.exists(os.path.join(path, name)):
            other.append(name)
    for d in SCENE_MODALITIES:
        if not os.path.isdir(os.path.join(path, d)):
            continue
        for sub in os.scandir(os.path.join(path, d)):
            name = f"{d}/{sub.name}"
            if name in own and sub.is_file():
                found.add(name)
            else:
                other.append(name)
            if len(other) >= 3:
                break
    if other or (found and not os.path.isfile(os.path.join(path, "frame.json"))):
        what = ", ".join(sorted(other)[:3]) if other else f"{', '.join(sorted(found)[:2])} without a frame.json"
        raise UsageError(f"--out: {out_dir} holds files render-scene did not write ({what}); give a new folder, or "
                       "one holding an earlier render-scene frame")


def write_frame(task: dict, images: dict, info: dict) -> dict:
    """Write one frame's modality files (atomically), then its manifest record; returns the
    frame's label (the plan's, with ``info``: the image-derived fields, and its files)."""
    seq_dir, stem = task["out"], f"{task['frame']:06d}"
    rel = {m: relpath(m, stem) for m in task["modalities"]}
    output = task["cfg"]["output"]
    digests = {rel[m]: F.atomic_write_image(os.path.join(seq_dir, rel[m]), images[m], **write_options(m, output))
               for m in task["modalities"]}
    label = dict(task["label"])
    label.update(info)
    label["files"] = rel
    F.write_frame_record(seq_dir, task["frame"], {"frame": task["frame"], "label": label, "files": digests})
    return label


def frame_seeds(seed: int, frame: int) -> tuple:
    """(render seed, degradation SeedSequence) of a frame: child ``frame`` of
    ``SeedSequence(seed).spawn(...)``; the render seed is its first word mod 2³¹, the
    degradation stream its first child."""
    child = np.random.SeedSequence(seed, spawn_key=(frame,))
    return int(child.generate_state(1)[0] % 2**31), np.random.SeedSequence(seed, spawn_key=(frame, 0))
