"""Running planned sequences: claim their folders, compile what a fresh install lacks, render
every missing frame on the pool, and finish each sequence (labels and manifest)."""

from __future__ import annotations

import sys
import time

from . import folder, jit, pool

def run_plans(jobs: list, frame_fn, *, config_text, workers: int | None = None, shard: tuple | None = None,
              scheduler: str | None = None, quiet: bool = False, quality: str = "fast", desc: str | None = None,
              ready=None) -> list:
    """Render the (plan, sequence folder) pairs: prepare folders, run every missing frame of
    this ``shard`` (K, N) with ``frame_fn`` (a task → its label, writing the frame: picklable)
    on ``workers`` processes or the dask cluster at ``scheduler`` (one progress bar, none when
    ``quiet``), then assemble labels and manifests. ``config_text(cfg)``: a configuration as
    the TOML text of ``config.toml``; ``quality``: the shading preset, whose kernels a fresh
    install compiles first; ``ready``: :func:`.pool.execute`'s. Returns one stats dict per
    sequence."""
    opts = {"shard": shard, "scheduler": scheduler, "quiet": quiet, "quality": quality, "desc": desc,
            "config_text": config_text, "ready": ready}
    workers = workers or pool.default_workers()
    if scheduler is None:
        workers = pool.fit_workers([plan["camera"] for plan, _ in jobs], workers)
    client = pool.connect_scheduler(scheduler) if scheduler is not None else None
    try:
        return _run_plans(jobs, frame_fn, opts, workers, client)
    finally:
        if client is not None:
            client.close()


def _run_plans(jobs: list, frame_fn, opts: dict, workers: int, client) -> list:
    claims = []
    try:
        for plan, seq_dir in jobs:
            claims.append(folder.prepare_sequence(plan, seq_dir, config_text=opts["config_text"](plan["cfg"]),
                                                  shared=opts["shard"] is not None))
    except BaseException:
        for claim in reversed(claims):  # a refused dataset leaves none of its other folders behind
            claim.undo()
        raise
    try:
        return _render_claimed(jobs, frame_fn, opts, workers, client)
    finally:
        for claim in claims:
            claim.release()


def _shard_frames(plan: dict, shard: tuple | None) -> set:
    wanted = folder.frames_to_write(plan)
    return set(wanted) if shard is None else {i for i in wanted if i % shard[1] == shard[0] - 1}


def _render_claimed(jobs: list, frame_fn, opts: dict, workers: int, client) -> list:
    all_tasks, stats = [], []
    for plan, seq_dir in jobs:
        tasks, skipped = folder.tasks_for(plan, seq_dir, opts["shard"])
        all_tasks += tasks
        stats.append({"name": plan["name"], "dir": seq_dir, "rendered": len(tasks), "skipped": skipped,
                      "frames": len(plan["result"]["frames"]),
                      "visible": sum(f["visible"] for f in plan["result"]["frames"])})
    skipped = sum(s["skipped"] for s in stats)
    t0 = time.perf_counter()
    serial = pool.frame_threads(workers, len(all_tasks)) == 1
    missing = (jit.kernels_not_compiled(opts["quality"], serial)
               if all_tasks and opts["scheduler"] is None else [])
    if missing:
        jit.compile_kernels(missing, quiet=opts["quiet"], serial=serial)
    bar = progress_bar(len(all_tasks) + skipped, skipped, opts["desc"] or jobs[0][0]["name"], opts["quiet"])
    try:
        for _ in pool.execute(all_tasks, frame_fn, workers=workers, client=client, progress=bar, ready=opts["ready"]):
            pass
    except BaseException:
        folder.remove_incomplete_frames(all_tasks)  # the workers have stopped: no frame is written any more
        raise
    finally:
        bar.close()
    elapsed = time.perf_counter() - t0
    for (plan, seq_dir), s in zip(jobs, stats):
        # this run rendered its frames or checked their files before skipping them
        s.update(folder.finish_sequence(plan, seq_dir, verified=_shard_frames(plan, opts["shard"])))
        s["seconds"] = elapsed
        s["shard"] = opts["shard"]
    return stats


def progress_bar(total: int, initial: int, desc: str, quiet: bool):
    """A tqdm bar of frames on stderr (disabled when ``quiet``)."""
    from tqdm import tqdm
    return tqdm(total=total, initial=initial, desc=desc, unit="frame", disable=quiet, file=sys.stderr,
                dynamic_ncols=True, smoothing=0.1, mininterval=0.5)
