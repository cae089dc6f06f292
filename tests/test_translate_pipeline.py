"""Stage-1 plumbing: pairs and crops, lr schedule, training loop with resume, model folders,
translating a scene, stage-1 scores, the paper tables and the qualitative figure.

A tiny one-layer translator is registered for these tests so they check the plumbing alone (the
real models are tested in test_translate_gan.py / test_translate_denoisers.py)."""

import dataclasses
import json
import types

import numpy as np
import pytest
import torch
from torch import nn

from spc3d import io, specs, translate
from spc3d.checkpoints import CheckpointPolicy
from spc3d.evaluation import figures, tables
from spc3d.evaluation.figures import pick_view, qualitative_figure
from spc3d.evaluation.stage1 import score_images
from spc3d.inputs.augment import AugmentSettings, augment_scene
from spc3d.inputs.build import simulate_scene
from spc3d.inputs.scenes import write_builtin_scene
from spc3d.names import LABELS, STAGE1_METHODS, translator_settings
from spc3d.physics import spc
from spc3d.specs.translators import model_config
from spc3d.training import run
from spc3d.translate import base, data, model_io, train
from spc3d.translate.apply import self_ensemble, translate_scene

from conftest import InterruptAt, Interrupted


@dataclasses.dataclass(frozen=True)
class TinyConfig:
    width: int = 4  # hidden channels
    lr: float = 1e-2  # Adam learning rate


class TinyTranslator(base.TranslatorBase):
    """conv-relu-conv-sigmoid; enough to learn a colour map of the binary image."""

    multiple = 4

    def __init__(self, cfg, device, vgg_weights=None):
        self.device = device
        self.net = nn.Sequential(nn.Conv2d(3, cfg.width, 3, padding=1), nn.ReLU(), nn.Conv2d(cfg.width, 3, 1))
        self.opt = torch.optim.Adam(self.net.parameters(), lr=cfg.lr)

    def modules(self):
        return {"G": self.net}

    def optimizers(self):
        return {"G": self.opt}

    def forward_image(self, binary):
        return torch.sigmoid(self.net(binary))

    def train_step(self, binary, rgb):
        loss = (self.forward_image(binary) - rgb).abs().mean()
        self.opt.zero_grad()
        loss.backward()
        self.opt.step()
        return {"loss": loss.item()}


TINY_PAPER = {"width": 8}


@pytest.fixture
def tiny_registered(monkeypatch):
    """The tiny translator as a model of the run: its spec (settings from here) and its module."""
    here = f"{__name__}:Tiny"
    spec = specs.TranslatorSpec("tiny", "Tiny", __name__, config=f"{here}Config", paper=f"{__name__}:TINY_PAPER")
    monkeypatch.setitem(specs.TRANSLATORS, "tiny", spec)
    module = types.SimpleNamespace(Config=TinyConfig, PAPER=TINY_PAPER, Translator=TinyTranslator)
    monkeypatch.setitem(translate.MODULES, "tiny", module)
    return "tiny"


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Two tiny built-in scenes: one augmented for training, one simulated for evaluation."""
    root = tmp_path_factory.mktemp("stage1")
    for name in ("orchard", "gallery"):
        write_builtin_scene(name, root / "scenes" / name, height=32, width=40, views=9, supersample=1)
        simulate_scene(root / "scenes" / name, root / "spc" / name, spc.SPCParams(frames=4), seed=0)
    augment_scene(
        root / "scenes" / "orchard",
        root / "spc" / "orchard",
        root / "augment" / "orchard",
        count=6,
        settings=AugmentSettings(),
        seed=0,
    )
    return root


def test_registry_matches_the_workflow_names():
    assert tuple(translate.MODULES) == STAGE1_METHODS
    with pytest.warns(DeprecationWarning, match=r"TRANSLATORS is now spc3d\.translate\.MODULES"):
        assert translate.TRANSLATORS is translate.MODULES  # the old name, for plugins
    with pytest.raises(AttributeError, match="no attribute 'MODELS'"):
        translate.MODELS  # noqa: B018
    for name, module in translate.MODULES.items():
        assert specs.settings_classes(name) == (module.Config, module.PAPER), name  # the torch-free ones
        assert dataclasses.is_dataclass(module.Config) and set(module.PAPER) <= {
            f.name for f in dataclasses.fields(module.Config)
        }, name
        assert name in LABELS


def test_pairs_are_aligned_and_averaged(world):
    b1, rgb = data.load_pairs([world / "augment" / "orchard"], frames=1)
    b4, _ = data.load_pairs([world / "augment" / "orchard"], frames=4)
    b1, rgb, b4 = torch.stack(b1), torch.stack(rgb), torch.stack(b4)
    assert b1.shape == rgb.shape == (6, 3, 32, 40)
    assert set(torch.unique(b1).tolist()) <= {0.0, 1.0}
    assert set(torch.unique(b4 * 4).tolist()) <= {0.0, 1.0, 2.0, 3.0, 4.0}
    with pytest.raises(ValueError, match="stage1.frames=5.*K=4"):
        data.load_pairs([world / "augment" / "orchard"], frames=5)
    with pytest.raises(FileNotFoundError, match="run the augment_scene rule"):
        data.load_pairs([world / "spc" / "gallery" / "nothing"], frames=1)


def test_sampler_crops_the_same_pixels_and_is_reproducible():
    binary = torch.arange(2 * 3 * 10 * 12, dtype=torch.float32).view(2, 3, 10, 12)
    s1, s2 = data.PairSampler(binary, binary + 0.5, 3, 6, seed=1), data.PairSampler(binary, binary + 0.5, 3, 6, seed=1)
    b, r = s1()
    assert b.shape == (3, 3, 6, 6) and torch.equal(r, b + 0.5)  # paired: identical windows
    assert torch.equal(s2()[0], b)
    state = s1.state()
    nxt = s1()[0]
    s1.load(state)
    assert torch.equal(s1()[0], nxt)
    unpaired = data.PairSampler(binary, binary + 0.5, 64, 6, seed=1, paired=False)
    b, r = unpaired()
    assert not torch.equal(r, b + 0.5)
    with pytest.raises(ValueError, match="crop=11 exceeds the smallest"):
        data.PairSampler(binary, binary, 1, 11, seed=0)


def test_sampler_takes_scenes_of_different_sizes():
    """LLFF captures keep their aspect ratio: 123- and 126-pixel-high pairs train side by side."""
    binary = [torch.rand(3, 123, 168), torch.rand(3, 126, 168), torch.rand(3, 124, 170)]
    rgb = [b + 1 for b in binary]
    b, r = data.PairSampler(binary, rgb, 8, 64, seed=0)()
    assert b.shape == r.shape == (8, 3, 64, 64) and torch.equal(r, b + 1)
    with pytest.raises(ValueError, match="crop=124 exceeds the smallest training image side \\(123 px\\)"):
        data.PairSampler(binary, rgb, 1, 124, seed=0)


def test_lr_schedule_is_constant_then_linear_to_zero():
    s = train.TrainSettings(iterations=100, decay_from=0.5)
    assert [train.lr_scale(i, s) for i in (1, 50, 75, 100)] == [1.0, 1.0, 0.5, 0.0]
    with pytest.raises(ValueError, match="decay_from"):
        train.TrainSettings(decay_from=1.5)


def test_model_config_presets_and_unknown_keys(tiny_registered):
    assert model_config("tiny", {}).width == 4
    assert model_config("tiny", {"preset": "paper"}).width == 8
    assert model_config("tiny", {"preset": "paper", "width": 3}).width == 3
    with pytest.raises(ValueError, match="stage1.tiny: unknown setting.*'depth'"):
        model_config("tiny", {"depth": 3})
    with pytest.raises(ValueError, match="unknown stage-1 method 'pix3pix'"):
        model_config("pix3pix", {})
    with pytest.raises(ValueError, match="preset='huge'"):
        model_config("tiny", {"preset": "huge"})


def test_translator_settings_merge_the_method_train_block():
    stage1 = {"train": {"iterations": 10, "crop": 32}, "pix2pix": {"ngf": 8, "train": {"iterations": 3}}}
    assert translator_settings(stage1, "pix2pix") == ({"ngf": 8}, {"iterations": 3, "crop": 32})
    assert translator_settings(stage1, "cyclegan") == ({}, {"iterations": 10, "crop": 32})


def test_translate_pads_and_crops_back(tiny_registered):
    model = TinyTranslator(TinyConfig(), torch.device("cpu"))
    x = torch.rand(2, 3, 7, 9)
    y = model.translate(x)
    assert y.shape == x.shape and 0 <= y.min() and y.max() <= 1
    padded, size = base.pad_to_multiple(x, 4)
    assert padded.shape[-2:] == (8, 12) and size == (7, 9)
    assert base.pad_to_multiple(torch.rand(1, 3, 1, 1), 16)[0].shape[-2:] == (16, 16)  # too small to reflect
    with pytest.raises(ValueError, match=r"\(B, 3, H, W\)"):
        model.translate(torch.rand(3, 7, 9))


TINY_TRAIN = {"crop": 16, "log_every": 5, "decay_from": 1.0}


def _job(world, out, ckpt, iterations, tiny):
    return train.TranslatorJob(
        tiny,
        train.training_data("fixed", [world / "augment" / "orchard"]),
        out,
        {},
        {**TINY_TRAIN, "iterations": iterations},
        seed=3,
        checkpoint=ckpt,
    )


def _train(world, out, ckpt, iterations, tiny):
    return train.train_translator(_job(world, out, ckpt, iterations, tiny))


def test_training_learns_writes_its_folder_and_resumes(world, tmp_path, tiny_registered):
    torch.set_num_threads(1)
    full = _train(world, tmp_path / "full", tmp_path / "full.pt", 40, tiny_registered)
    curve = io.read_json(tmp_path / "full" / "train.json")
    assert curve["seed"] == 3 and curve["parameters"] == {"G": 4 * 27 + 4 + 3 * 4 + 3} and curve["pairs"] == 6
    assert {"train_s", "peak_rss_mb", "settings", "train"} <= set(curve)
    assert (tmp_path / "full" / "curve.png").stat().st_size > 1000
    losses = np.loadtxt(tmp_path / "full" / "curve.csv", delimiter=",", skiprows=1)[:, 1]
    assert losses[-1] < losses[0]
    # killed at iteration 23 (checkpoints every 10), rerun: resumed from 20, the same losses and curve
    setup = train.setup_training(_job(world, tmp_path / "resumed", tmp_path / "resume.pt", 40, tiny_registered))
    with pytest.raises(Interrupted):
        run(
            InterruptAt(train.TranslatorTrainer(setup.model, setup.sampler, setup.settings), 23),
            40,
            setup.checkpoint,
            CheckpointPolicy(fraction=0.25, minutes=0),
        )
    resumed = _train(world, tmp_path / "resumed", tmp_path / "resume.pt", 40, tiny_registered)
    assert resumed["resumed_from"] == 20 and resumed["checkpoint"]["discarded"] is None
    assert resumed["final_losses"]["loss"] == pytest.approx(full["final_losses"]["loss"], rel=1e-6)
    assert (tmp_path / "resumed" / "curve.csv").read_text() == (tmp_path / "full" / "curve.csv").read_text()


def test_translate_scene_and_stage1_scores(world, tmp_path, tiny_registered, lpips_cache):
    _train(world, tmp_path / "model", None, 5, tiny_registered)
    rec = translate_scene(
        tmp_path / "model", world / "spc" / "gallery", world / "scenes" / "gallery", tmp_path / "translated"
    )
    assert rec["views"] == 9 and rec["method"] == "tiny" and rec["ensemble"] == 1
    img = io.read_rgb(tmp_path / "translated" / "images" / "image000.png")
    assert img.shape == (32, 40, 3)
    # the 4-flip self-ensemble is recorded and writes images of the same size
    four = translate_scene(
        tmp_path / "model", world / "spc" / "gallery", world / "scenes" / "gallery", tmp_path / "four", ensemble=4
    )
    assert four["ensemble"] == 4 and json.loads((tmp_path / "four" / "translate.json").read_text())["ensemble"] == 4
    assert io.read_rgb(tmp_path / "four" / "images" / "image000.png").shape == (32, 40, 3)
    with pytest.raises(ValueError, match=r"stage1.ensemble must be one of \[1, 2, 4\].*got 3"):
        translate_scene(
            tmp_path / "model", world / "spc" / "gallery", world / "scenes" / "gallery", tmp_path / "x", ensemble=3
        )
    assert not (tmp_path / "x").exists()
    scores = score_images(
        world / "scenes" / "gallery" / "images",
        world / "scenes" / "gallery",
        tmp_path / "gt.json",
        "gt",
        lpips_dir=lpips_cache,
    )
    assert scores["mean"]["psnr"] == float("inf") and scores["mean"]["lpips_alex"] == pytest.approx(0, abs=1e-6)
    assert sorted(scores["views"]) == ["image000", "image008"]
    with pytest.raises(FileNotFoundError, match="no image for view"):
        score_images(tmp_path, world / "scenes" / "gallery", tmp_path / "x.json", "empty", lpips_dir=lpips_cache)


def test_self_ensemble_undoes_each_flip():
    x = torch.rand(2, 3, 5, 7, generator=torch.Generator().manual_seed(0))
    # an equivariant map (pointwise) is unchanged by the ensemble; one pass is the map itself
    assert torch.allclose(self_ensemble(torch.sqrt, x, 4), torch.sqrt(x), atol=1e-6)
    assert torch.equal(self_ensemble(torch.sqrt, x, 1), torch.sqrt(x))
    # a map that adds a ramp along the width: the mirror pass adds the reversed ramp, their mean is constant
    ramp = torch.arange(7.0)
    out = self_ensemble(lambda b: b + ramp, x, 2)
    assert torch.allclose(out, x + 3.0, atol=1e-6)
    # a ramp along the height survives the horizontal mirror but is flattened by the vertical ones
    col = torch.arange(5.0)[:, None]
    assert torch.allclose(self_ensemble(lambda b: b + col, x, 2), x + col, atol=1e-6)
    assert torch.allclose(self_ensemble(lambda b: b + col, x, 4), x + 2.0, atol=1e-6)
    with pytest.raises(ValueError, match="stage1.ensemble"):
        self_ensemble(torch.sqrt, x, 8)


def test_load_translator_names_a_missing_model(tmp_path):
    with pytest.raises(FileNotFoundError, match="model.pt is missing.*train_translator"):
        model_io.load_translator(tmp_path)


def _metrics(path, combo, psnr):
    io.write_json(
        path,
        {
            "scene": "s",
            "combination": combo,
            "seed": 0,
            "frames": None if combo.startswith("gt") else 1,
            "per_view": [{"view": "v0", "psnr": psnr}],
            "mean": {"psnr": psnr, "ssim": psnr / 40, "lpips_alex": 1 / psnr, "lpips_vgg": 1 / psnr},
        },
    )
    return str(path)


def test_two_stage_and_stage1_tables(tmp_path):
    files = [
        _metrics(tmp_path / f"{i}.json", c, p)
        for i, (c, p) in enumerate(
            [("pix2pixhd+nerf-grid", 22.0), ("restormer+3dgs", 23.0), ("diffusion+3dgs", 20.0), ("gt+3dgs", 30.0)]
        )
    ]
    df = tables.two_stage_table(files, tmp_path / "two_stage", "nerf-grid")
    assert list(df["combination"][:2]) == ["pix2pixhd+nerf-grid", "pix2pixhd+3dgs"]
    md = (tmp_path / "two_stage.md").read_text()
    assert "**23.00**" in md and "*22.00*" in md and "DiffBIR stand-in" in md and "22.7" in md
    s1 = []
    for i, (src, p, K) in enumerate(
        [("pix2pixhd", 21.0, 1), ("mle", 19.0, 1), ("none", 9.0, 1), ("mle-k16", 24.0, 16), ("pix2pixhd-pub", 8.0, 1)]
    ):
        s1.append(str(tmp_path / f"s{i}.json"))
        io.write_json(
            s1[-1],
            {
                "scene": "s",
                "source": src,
                "frames": K,
                "mean": {"psnr": p, "ssim": 0.5, "lpips_alex": 0.3, "lpips_vgg": 0.4},
            },
        )
    df = tables.stage1_table(s1, tmp_path / "stage1", LABELS)
    # every source once: the published network is not added again as the spec's "-pub" twin
    assert list(df["approach"]) == [
        "Pix2PixHD",
        "MLE",
        "binary frame (no stage 1)",
        "Pix2PixHD; the published network",
        "MLE",
    ]
    assert list(df["combination"]) == ["pix2pixhd", "mle", "none", "pix2pixhd-pub", "mle-k16"]
    assert list(df["K"]) == [1, 1, 1, 1, 16]
    md = (tmp_path / "stage1.md").read_text()
    assert "**21.00**" in md and "**24.00**" in md and "MLE (K = 16)" in md
    # Translators with their physics prior: one "prior" row per blur, its runs the scenes x seeds
    # (two translators of one seed share a run; the gain differs between seeds)
    s1 = []
    for seed, src, p, gain in ((0, "pix2pix", 21.0, 0.2), (0, "restormer", 20.0, 0.2), (1, "pix2pix", 23.0, 0.3)):
        s1.append(str(tmp_path / f"p{seed}{src}.json"))
        scores = {"ssim": 0.5, "lpips_alex": 0.3, "lpips_vgg": 0.4}
        prior = {"sigma": 2.0, "gain": [gain] * 3, "mean": {"psnr": 18.0 + seed, **scores}}
        io.write_json(
            s1[-1],
            {"scene": "s", "source": src, "frames": 1, "seed": seed, "prior": prior, "mean": {"psnr": p, **scores}},
        )
    df = tables.stage1_table(s1, tmp_path / "stage1p", LABELS).set_index("combination")
    assert list(df.index) == ["pix2pix", "restormer", "prior"]
    assert df.loc["prior", "runs"] == 2 and df.loc["prior", "psnr_mean"] == pytest.approx(18.5)
    assert df.loc["pix2pix", "runs"] == 2 and df.loc["prior", "approach"].startswith("Physics prior")


def test_qualitative_figure(world, tmp_path):
    view = pick_view(world / "scenes" / "gallery")
    assert view == "image000"
    with pytest.raises(ValueError, match="not a held-out view"):
        pick_view(world / "scenes" / "gallery", "image001")
    recon = tmp_path / "recon" / "gt+3dgs"
    (recon / "renders").mkdir(parents=True)
    io.write_image(
        recon / "renders" / f"{view}.png", io.read_rgb(world / "scenes" / "gallery" / "images" / f"{view}.png")
    )
    (tmp_path / "unposed").mkdir()  # a row COLMAP could not pose: train.json only, no renders -> no panel
    out = tmp_path / "fig.png"
    recons = {"gt+3dgs": str(recon), "mle-k4+3dgs@mle-k4": str(tmp_path / "unposed")}
    qualitative_figure(world / "scenes" / "gallery", world / "spc" / "gallery", recons, out, labels=LABELS)
    assert io.read_image(out).shape[2] in (3, 4)


def test_long_panel_titles_wrap_inside_their_panels():
    """Row labels as long as the tables' wrap to several lines and no two titles of a row overlap."""
    long = "Physics prior (blurred MLE, the translators' untrained start) + nerf-grid\n23.58 dB"
    assert all(len(line) <= figures.TITLE_CHARS for line in figures.wrap_title(long).split("\n")[:-1])
    assert figures.wrap_title("short\n1.00 dB") == "short\n1.00 dB"
    panels = [(long, np.full((24, 32, 3), 0.5))] * 7
    fig = figures.panel_figure(panels, "scene", per_row=6)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    boxes = [ax.title.get_window_extent(renderer) for ax in fig.axes if ax.get_title()]
    assert len(boxes) == 7
    for a, b in zip(boxes[:5], boxes[1:6]):  # neighbours in the first row
        assert a.x1 <= b.x0, (a, b)
    assert all(box.y1 <= fig.bbox.y1 for box in boxes)  # inside the figure


def test_restormer_starts_from_a_published_checkpoint(world, tmp_path):
    """stage1.restormer.checkpoint: an official-format .pth ({"params": state_dict}) is loaded and,
    with 0 iterations, is exactly the model that translates (the paper's pretrained variant)."""
    from spc3d.translate import restormer

    tiny = {"dim": 8, "heads": [1, 1, 1, 1], "prior_sigma": 0.0}  # published weights: no physics prior
    torch.manual_seed(5)
    published = restormer.Translator(model_config("restormer", tiny), torch.device("cpu"))
    torch.save({"params": published.net.state_dict()}, tmp_path / "real_denoising.pth")
    pairs = train.training_data("fixed", [world / "augment" / "orchard"])
    rec = train.train_translator(
        train.TranslatorJob(
            "restormer",
            pairs,
            tmp_path / "model",
            {**tiny, "checkpoint": str(tmp_path / "real_denoising.pth")},
            {"iterations": 0, "crop": 16},
            seed=0,
        )
    )
    assert rec["pretrained"].endswith("real_denoising.pth") and rec["iterations"] == 0
    _, loaded = model_io.load_translator(tmp_path / "model")
    x = torch.rand(1, 3, 16, 24).round()
    assert torch.equal(loaded.translate(x), published.translate(x))
    with pytest.raises(ValueError, match="real_denoising.pth: checkpoint does not match"):
        train.train_translator(
            train.TranslatorJob(
                "restormer",
                pairs,
                tmp_path / "model2",
                {"dim": 16, "prior_sigma": 0.0, "checkpoint": str(tmp_path / "real_denoising.pth")},
                {"iterations": 0},
            )
        )
