"""Splitting the frames of several sequences into named subsets (train, val, test, ...).

A split spec is ``name=share,name=share,...``: every share a fraction (the fractions sum to 1
within 1e-9) or every share a count (whole numbers summing to the number of items); a single
``name=1`` is the fraction 1 (everything in one split). Items are
frames (all sequences' frames pooled) or whole sequences. They are shuffled with
``numpy.random.default_rng(seed).permutation`` and cut in the order the names are given; a
fraction becomes a count by the largest-remainder (Hamilton) method: each split gets
``floor(f · N)``, and the items left over go one each to the splits with the largest remainders
``f · N − floor(f · N)``, ties to the split named first. Every split must get at least one item.
Within a split the items keep the input order (sequence as given, then frame number).
"""

from __future__ import annotations

import math
import re

import numpy as np

__all__ = ["SPLIT_BY", "assign", "parse_split_spec", "share_counts"]

SPLIT_BY = ("frame", "sequence")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")
_FRACTION_TOL = 1e-9


def parse_split_spec(text: str) -> tuple[tuple[str, float | int], ...]:
    """``"train=0.8,val=0.2"`` → ``(("train", 0.8), ("val", 0.2))``; ``"train=90,test=10"`` →
    counts (ints). ValueError with one line saying what is allowed."""
    allowed = ("must be NAME=SHARE[,NAME=SHARE...] with folder-safe unique names (letters, digits, '_', '-') "
               "and either fractions summing to 1 or whole counts")
    items = [s.strip() for s in str(text).split(",")]
    out, seen = [], set()
    for item in items:
        name, sep, share = item.partition("=")
        name, share = name.strip(), share.strip()
        if not sep or not _NAME.match(name):
            raise ValueError(f"{allowed}; got {text!r}")
        if name in seen:
            raise ValueError(f"names must be unique, {name!r} appears twice in {text!r}")
        seen.add(name)
        out.append((name, share))
    if all(re.fullmatch(r"\d+", s) for _, s in out):
        counts = tuple((n, int(s)) for n, s in out)
        if any(c < 1 for _, c in counts):
            raise ValueError(f"counts must be whole numbers >= 1; got {text!r}")
        if len(counts) == 1 and counts[0][1] == 1:  # "train=1": one split holding everything
            return ((counts[0][0], 1.0),)
        return counts
    try:
        fracs = [(n, float(s)) for n, s in out]
    except ValueError:
        raise ValueError(f"{allowed}; got {text!r}") from None
    if not all(math.isfinite(f) and 0 < f <= 1 for _, f in fracs):
        raise ValueError(f"fractions must be finite numbers in (0, 1] (or all shares whole counts); got {text!r}")
    total = math.fsum(f for _, f in fracs)
    if abs(total - 1.0) > _FRACTION_TOL:
        raise ValueError(f"fractions must sum to 1 (within 1e-9), got {total!r} from {text!r}")
    return tuple(fracs)


def share_counts(spec, n: int, what: str = "frame") -> list[int]:
    """Number of items of each split of ``spec`` among ``n`` (largest remainder for fractions).
    ValueError if counts do not add up to ``n`` or a split would get nothing."""
    shares = [s for _, s in spec]
    if all(isinstance(s, int) for s in shares):
        if sum(shares) != n:
            raise ValueError(f"counts sum to {sum(shares)} but there are {n} {what}(s) to split")
        counts = list(shares)
    else:
        exact = [s * n for s in shares]
        counts = [math.floor(e) for e in exact]
        left = n - sum(counts)
        # largest remainder first; ties to the split named first (stable sort)
        order = sorted(range(len(spec)), key=lambda i: -(exact[i] - counts[i]))
        for i in order[:left]:
            counts[i] += 1
    empty = [name for (name, _), c in zip(spec, counts) if c == 0]
    if empty:
        raise ValueError(f"split {empty[0]!r} gets no {what} of {n} (needs more {what}s, or a larger share)")
    return counts


def assign(items_per_sequence: list[list], spec, *, by: str = "frame", seed: int = 0) -> dict[str, list]:
    """Split the items (one list per sequence, in order) into ``{name: [item, ...]}``.

    ``by="frame"`` pools all items; ``by="sequence"`` keeps each sequence's items together.
    The shuffle is ``np.random.default_rng(seed).permutation`` of the pooled items (or of the
    sequences); each split keeps the input order of its items.
    """
    if by not in SPLIT_BY:
        raise ValueError(f"split_by must be one of {', '.join(SPLIT_BY)}; got {by!r}")
    rng = np.random.default_rng(seed)
    if by == "frame":
        pooled = [(s, k) for s, items in enumerate(items_per_sequence) for k in range(len(items))]
        counts = share_counts(spec, len(pooled), "frame")
        perm = rng.permutation(len(pooled))
        out, start = {}, 0
        for (name, _), c in zip(spec, counts):
            chosen = sorted(pooled[i] for i in perm[start:start + c])
            out[name] = [items_per_sequence[s][k] for s, k in chosen]
            start += c
        return out
    counts = share_counts(spec, len(items_per_sequence), "sequence")
    perm = rng.permutation(len(items_per_sequence))
    out, start = {}, 0
    for (name, _), c in zip(spec, counts):
        out[name] = [item for s in sorted(perm[start:start + c]) for item in items_per_sequence[s]]
        start += c
    return out
