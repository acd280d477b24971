"""The modality table (raytrace.dataset.modalities): one entry per output, read by the writers,
the folder checks, the exports and render-scene; and the semantic part image it declares,
checked against the mask and the components listed in scenario.json."""

import json
from pathlib import Path

import numpy as np

import cli
from raytrace.export import _read as export
from raytrace import files as F
from raytrace.dataset import folder
from raytrace.dataset.modalities import DEFAULT, MODALITIES, NAMES, PICTURES, relpath
from raytrace.model import SEMANTIC_CLASSES
from tests.cli_helpers import run_main

SMALL = ["--target", "cassini", "--pattern", "spiral", "--frames", "2", "--width", "160", "--height", "120",
         "--quiet", "--workers", "1"]


def test_the_table_is_what_the_command_line_and_the_exports_offer():
    assert cli.MODALITIES == NAMES and len(set(NAMES)) == len(NAMES)
    assert all(m.ext in (".png", ".exr") and m.name == n for n, m in MODALITIES.items())
    # everything but the pipeline's own images has a producer
    assert {n for n, m in MODALITIES.items() if m.produce is None} == {"rgb", "rgb_degraded", "signal_e", "saturation"}
    assert set(PICTURES) == {"rgb", "rgb_degraded"} and export._IMAGE_MODALITIES == PICTURES
    assert "hdr" not in DEFAULT and "semantic" not in DEFAULT and "mask" in DEFAULT
    assert relpath("depth", 12) == "depth/000012.exr" and relpath("mask", "000000") == "mask/000000.png"
    assert set(folder.SCENE_MODALITIES) <= set(NAMES)


def test_semantic_image_is_the_part_class_of_each_masked_pixel(tmp_path, capsys):
    seq = tmp_path / "seq"
    assert run_main(*SMALL, "--modalities", "mask,semantic", "--out", seq) == 0
    scenario = json.loads((seq / "scenario.json").read_text())
    # instance id k + 1 -> the class of component k, as scenario.json lists it; 0 stays 0
    lut = np.zeros(len(scenario["target_model"]["components"]) + 1, dtype=np.int64)
    for c in scenario["target_model"]["components"]:
        lut[c["id"]] = SEMANTIC_CLASSES.index(c["semantic"]) + 1
    labels = json.loads((seq / "labels.json").read_text())
    for label in labels:
        assert set(label["files"]) == {"mask", "semantic"}
        ids = F.read_image(str(seq / label["files"]["mask"]))
        sem = F.read_image(str(seq / label["files"]["semantic"]))
        assert sem.dtype == np.uint8 and sem.shape == ids.shape
        assert ids.any() and np.array_equal(sem, lut[ids])
        assert len(np.unique(sem)) > 2  # several part classes in view, not a constant image


def test_the_defaults_are_written_when_no_modality_is_named(tmp_path, capsys):
    cfg, _ = cli.resolve_config(cli.build_parser().parse_args([]))
    assert cfg["output"]["modalities"] == list(DEFAULT)
    cfg, _ = cli.resolve_config(cli.build_parser().parse_args(["--degrade", "none"]))
    assert cfg["output"]["modalities"] == [m for m in DEFAULT if m != "rgb_degraded"]
    seq = tmp_path / "seq"
    assert run_main(*SMALL, "--modalities", "mask", "--out", seq) == 0
    assert sorted(p.name for p in Path(seq).iterdir() if p.is_dir() and not p.name.startswith(".")) == ["mask", "model"]
