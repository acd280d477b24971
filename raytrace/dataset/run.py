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
            "config_text": config_text, "ready": ready, "auto_workers": workers is None}
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
    if opts["auto_workers"] and client is None and pool.in_process(all_tasks, workers, opts["quality"]):
        workers = 1
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


def summary_line(s: dict, elapsed: float) -> str:
    """The one-line summary of a sequence's stats (:func:`run_plans`) after ``elapsed`` s."""
    rate = f", {s['rendered'] / elapsed:.2f} frames/s" if s["rendered"] and elapsed > 0 else ""
    if s["complete"]:
        state = "labels.json and manifest.json written"
    elif s.get("corrupt"):
        frame, rel = s["corrupt"][0]
        more = f" and {len(s['corrupt']) - 1} more" if len(s["corrupt"]) > 1 else ""
        state = (f"{s['present']} of {s['wanted']} frames complete; frame {frame}{more} does not match its manifest "
                 f"record ({rel}): rerun without --shard, or its shard, to render it again")
    else:
        state = (f"{s['present']} of {s['wanted']} frames present; labels.json is written when all are "
                 "(run the other shards, or rerun without --shard)")
    return (f"{s['name']}: {s['frames']} frames, {s['visible']} visible; rendered {s['rendered']}, "
            f"skipped {s['skipped']} complete, in {elapsed:.1f} s{rate} -> {s['dir']}/ ({state})\n")


def stats_table(stats: list, modalities: list, elapsed: float, root: str) -> str:
    """The table of counts of a dataset's sequences (their :func:`run_plans` stats) and a total
    line, as ``python cli.py dataset`` prints it."""
    lines = [f"{'sequence':<26} {'frames':>6} {'visible':>7} {'rendered':>8} {'skipped':>7} {'complete':>8}"]
    for s in stats:
        lines.append(f"{s['name']:<26} {s['frames']:6d} {s['visible']:7d} {s['rendered']:8d} {s['skipped']:7d} "
                     f"{'yes' if s['complete'] else 'no':>8}")
    tot = {k: sum(s[k] for s in stats) for k in ("frames", "visible", "rendered", "skipped")}
    lines.append(f"{'total':<26} {tot['frames']:6d} {tot['visible']:7d} {tot['rendered']:8d} {tot['skipped']:7d}")
    lines.append(f"{len(stats)} sequences x {len(modalities)} modalities ({','.join(modalities)}) in {elapsed:.1f} s "
                 f"-> {root}/")
    return "\n".join(lines) + "\n"
