"""What the split-based writers (:mod:`.speedplus`, :mod:`.coco`) share: checking the
{split: [(sequence, frame), ...]} items they are given, and naming each frame's image uniquely
across sequences. (:mod:`.splits` assigns frames to splits.)"""

from __future__ import annotations

from collections import Counter

from ._read import _frame_file

__all__ = ["_check_splits", "_image_stems", "_frame_files"]


def _check_splits(splits) -> dict:
    """``splits`` as {name: [(sequence, frame), ...]}: plain names, at least one frame, no frame twice."""
    if not isinstance(splits, dict) or not splits:
        raise ValueError(f"splits must be a non-empty dict of split name → [(sequence, frame), ...], got {splits!r}")
    seen = set()
    for name, items in splits.items():
        if not isinstance(name, str) or not name or any(c in name for c in "/\\") or name.startswith("."):
            raise ValueError(f"split names must be plain file names such as 'train', 'val', 'test'; got {name!r}")
        for seq, f in items:
            key = (seq.root.resolve(), f.frame)
            if key in seen:
                raise ValueError(f"splits: frame {f.frame} of {seq.root} appears twice")
            seen.add(key)
    if not seen:
        raise ValueError("splits hold no frame; nothing to export")
    return splits


def _image_stems(splits: dict) -> dict:
    """File stem of every (sequence root, frame): ``NNNNNN`` (frame number) when all frames come from
    one sequence, else ``{folder name}_NNNNNN``, or ``s{k:04d}_NNNNNN`` (k: order of first
    appearance) when two sequence folders share a name."""
    roots = list(dict.fromkeys(seq.root.resolve() for items in splits.values() for seq, _ in items))
    names = Counter(r.name for r in roots)
    if len(roots) == 1:
        prefix = {roots[0]: ""}
    elif all(names[r.name] == 1 for r in roots):
        prefix = {r: f"{r.name}_" for r in roots}
    else:
        prefix = {r: f"s{k:04d}_" for k, r in enumerate(roots)}
    return {(seq.root.resolve(), f.frame): f"{prefix[seq.root.resolve()]}{f.frame:06d}"
            for items in splits.values() for seq, f in items}


def _frame_files(seq, f, modalities: tuple) -> list:
    """Paths of a frame's files of ``modalities``; ValueError naming the first one not listed."""
    out = []
    for m in modalities:
        path = _frame_file(seq, f, m)
        if path is None:
            raise ValueError(f"{seq.root / 'labels.json'}: frame {f.frame} lists no {m!r} file "
                             f"(files: {', '.join(sorted(f.files)) or 'none'})")
        out.append(path)
    return out

