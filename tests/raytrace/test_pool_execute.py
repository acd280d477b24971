"""The worker pool's ``execute``: a ready call queued per worker ahead of the frames, the frames
alone yielded and counted, a failed ready call raised."""

from __future__ import annotations

import functools
import os
import time

import pytest

from raytrace.dataset import pool

SLOW_READY_S = 2.0


def _frame(task: dict) -> dict:
    return {"frame": task["frame"], "pid": os.getpid(), "start": time.time()}


def _ready_once_slow(marker: str) -> None:
    """The first ready call anywhere (it creates ``marker``) loads for SLOW_READY_S; the others at once."""
    try:
        fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return
    time.sleep(SLOW_READY_S)
    os.write(fd, repr(time.time()).encode())
    os.close(fd)


def _ready_fails() -> None:
    raise RuntimeError("the worker could not load its kernels")


@pytest.fixture(autouse=True)
def _no_scenes(monkeypatch):
    monkeypatch.setattr(pool, "PREBUILD_SCENES", False)  # these tasks render no scene


class _Bar:
    n = 0

    def update(self, k: int) -> None:
        self.n += k


def test_a_ready_worker_renders_while_the_other_still_loads(tmp_path):
    marker = str(tmp_path / "slow")
    bar = _Bar()
    tasks = [{"frame": i} for i in range(6)]
    out = list(pool.execute(tasks, _frame, workers=2, progress=bar, ready=functools.partial(_ready_once_slow, marker)))
    assert sorted(r["frame"] for r in out) == list(range(6))  # the frames only, each once
    assert bar.n == 6
    slow_done = float(open(marker).read())
    # the other worker's frames started before the slow worker had loaded
    assert min(r["start"] for r in out) < slow_done - 0.5 * SLOW_READY_S


def test_a_failed_ready_call_is_raised():
    with pytest.raises(RuntimeError, match="could not load its kernels"):
        list(pool.execute([{"frame": i} for i in range(4)], _frame, workers=2, ready=_ready_fails))
