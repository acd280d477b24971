"""The imaging chain: PSFs, Bayer mosaic and demosaic, shot and read noise, quantisation.

``degrade`` works on any finite, nonnegative float image (H×W×3 RGB or H×W monochrome;
float32 in → float32 out, other floats are converted to float32, integers are refused) and
imports nothing from ``orbit`` or ``raytrace``. docs/degradation.md gives the maths.

Modules
-------
exposure   Radiance → linear sensor signal: auto exposure, or the camera equation.
psf        Airy, Gaussian, pillbox (defocus) and motion PSFs (L, θ from the image velocity),
           and their composition.
convolve   Mirror-padded convolution, direct or FFT picked by kernel size.
sensor     RGGB mosaic, Poisson shot noise, full well, read noise, ADC, demosaic (MHC in Numba,
           bilinear by OpenImageIO).
encode     sRGB transfer curve (IEC 61966-2-1), integer quantisation, linear → 8-bit sRGB codes.
artefacts  Camera artefacts: vignetting, PRNU/DSNU, hot pixels, smear, blooming, stray light and
           ghost, on-board JPEG.
chain      ``OpticsConfig``, ``DegradeConfig``, ``degrade`` and ``simulate_frame``: the physical
           chain in one call.
paper      The paper's groups D1–D4, bit-identical to ``skimage.util.random_noise``.
ablation   PSNR/SSIM(/LPIPS) cost of each paper group and physical stage, and a text table.
"""

from .ablation import (
    PHYSICAL_STAGES,
    AblationReport,
    AblationRow,
    Summary,
    format_ablation,
    physical_stage_configs,
    run_ablation,
)
from .artefacts import ArtefactConfig
from .chain import (
    ENCODINGS,
    DegradeConfig,
    FrameOutput,
    OpticsConfig,
    apply_optics,
    degrade,
    optics_psf,
    simulate_frame,
)
from .convolve import convolve_image
from .encode import dequantise, encode_srgb8, quantise, srgb_decode, srgb_encode
from .paper import (
    PAPER_GROUPS,
    PaperConfig,
    gaussian_noise,
    paper_blur,
    paper_degrade,
    poisson_noise,
)
from .psf import (
    airy_psf,
    compose,
    defocus_psf,
    defocus_radius_px,
    gaussian_psf,
    motion_from_velocity,
    motion_psf,
)
from .sensor import (
    DEMOSAIC_ALGORITHMS,
    SensorConfig,
    demosaic,
    mosaic_rggb,
    sensor_readout,
    simulate_sensor,
)

__all__ = [
    "DEMOSAIC_ALGORITHMS",
    "ENCODINGS",
    "PAPER_GROUPS",
    "PHYSICAL_STAGES",
    "AblationReport",
    "AblationRow",
    "ArtefactConfig",
    "DegradeConfig",
    "FrameOutput",
    "OpticsConfig",
    "PaperConfig",
    "SensorConfig",
    "Summary",
    "airy_psf",
    "apply_optics",
    "compose",
    "convolve_image",
    "defocus_psf",
    "defocus_radius_px",
    "degrade",
    "demosaic",
    "dequantise",
    "encode_srgb8",
    "format_ablation",
    "gaussian_noise",
    "gaussian_psf",
    "mosaic_rggb",
    "motion_from_velocity",
    "motion_psf",
    "optics_psf",
    "paper_blur",
    "paper_degrade",
    "physical_stage_configs",
    "poisson_noise",
    "quantise",
    "run_ablation",
    "sensor_readout",
    "simulate_frame",
    "simulate_sensor",
    "srgb_decode",
    "srgb_encode",
]
