"""Stage 1 online data and validation: fresh samples stay aligned, follow each scene's exposure and
their seed; validation stops on a plateau, keeps the best model, and a killed run resumes exactly.

Tiny built-in scenes (32 x 40, 9 views) and tiny translators: the plumbing, not the models."""

import dataclasses
import types

import numpy as np
import pytest
import torch
from torch import nn

from spc3d import io, specs, translate
from spc3d.cameras import split_views
from spc3d.checkpoints import Checkpoint, CheckpointPolicy
from spc3d.inputs import augment
from spc3d.inputs.augment import AugmentSettings
from spc3d.inputs.build import simulate_scene
from spc3d.inputs.scenes import write_builtin_scene
from spc3d.physics import spc
from spc3d.specs.translators import model_config, validation_settings
from spc3d.training import run
from spc3d.translate import base, model_io, online, train, validate
from spc3d.translate.camera import CAMERA_WHITE, from_camera

from conftest import InterruptAt, Interrupted

pytestmark = pytest.mark.usefixtures("one_torch_thread")
FLUX = {"orchard": 2.0e4, "gallery": 8.0e4}  # two exposures: ~0.3 and ~0.7 mean detection


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Two training scenes simulated at different flux scales (K = 4 stored frames)."""
    root = tmp_path_factory.mktemp("online")
    for name, flux in FLUX.items():
        write_builtin_scene(name, root / "scenes" / name, height=32, width=40, views=9, supersample=1)
        simulate_scene(root / "scenes" / name, root / "spc" / name, spc.SPCParams(frames=4), flux_scale=flux, seed=0)
    return root


def _dirs(world, names=tuple(FLUX)):
    return [world / "scenes" / n for n in names], [world / "spc" / n for n in names]


def _sampler(world, names=tuple(FLUX), frames=1, seed=0, crop=16, batch=3, paired=True):
    sources = online.load_sources(*_dirs(world, names), frames)
    return online.OnlineSampler(sources, batch, crop, seed, AugmentSettings(), paired=paired)


# --- online sampling -------------------------------------------------------------------------------


def test_sources_hold_the_training_views_only(world):
    sources = online.load_sources(*_dirs(world), frames=2)
    assert [s.name for s in sources] == list(FLUX) and [s.flux_scale for s in sources] == list(FLUX.values())
    train_views, held_out = split_views(9)
    assert all(len(s.views) == len(train_views) and s.params.frames == 2 for s in sources)
    images = io.read_rgb(world / "scenes" / "orchard" / "images" / "image000.png")  # a held-out view
    assert not any(np.allclose(v, spc.srgb_to_linear(images)) for v in sources[0].views)
    with pytest.raises(ValueError, match="belongs to scene 'gallery', not 'orchard'"):
        online.load_sources([world / "scenes" / "orchard"], [world / "spc" / "gallery"], 1)
    with pytest.raises(ValueError, match="crop=33 exceeds the smallest training image side \\(32 px\\)"):
        _sampler(world, crop=33)


def test_the_target_is_the_augmented_view_cropped(world):
    """The cheap path (warp only the crop) gives the pixels of augment.py's full warp, cropped, as
    the scene's camera exposure shows them (the translators' domain)."""
    sampler = _sampler(world, crop=16)
    replay = np.random.Generator(np.random.PCG64())
    replay.bit_generator.state = sampler.rng.bit_generator.state
    source, _, rgb = sampler.sample()
    scene = sampler.sources[replay.integers(2)]
    view = scene.views[replay.integers(len(scene.views))]
    p = augment.sample_params(replay, AugmentSettings())
    y, x = (int(replay.integers(0, n - 16 + 1)) for n in (32, 40))
    full = augment.augment_image(spc.linear_to_srgb(view).astype(np.float32), p)
    assert scene is source
    shown = from_camera(rgb, source.exposure)  # back to the display: the target is the view itself
    np.testing.assert_allclose(shown.permute(1, 2, 0).numpy(), full[y : y + 16, x : x + 16], atol=2e-5)


def test_online_pairs_are_aligned(world):
    """With many frames averaged, the input is the target crop's own detection probability map."""
    sampler = _sampler(world, names=("gallery",), frames=4000, crop=16)
    for _ in range(2):
        source, binary, rgb = sampler.sample()
        p = spc.detection_probability(
            spc.flux_from_srgb(from_camera(rgb, source.exposure).permute(1, 2, 0).numpy(), source.flux_scale),
            source.params,
        )
        mean = binary.permute(1, 2, 0).numpy()
        assert np.abs(mean - p).mean() < 0.01 and np.abs(mean - p).max() < 0.05  # sd <= 0.008 per pixel
        assert np.abs(mean - p[::-1]).mean() > 3 * np.abs(mean - p).mean()  # a misaligned map does not fit
    assert set(torch.unique(_sampler(world, frames=1)()[0]).tolist()) <= {0.0, 1.0}  # K = 1: bits


def test_each_scene_keeps_its_exposure(world):
    """Bit rates per scene match that scene's expected detection probability, not the other's."""
    sampler = _sampler(world, frames=1, crop=16)
    ones, expected, other = {n: [] for n in FLUX}, {n: [] for n in FLUX}, {n: [] for n in FLUX}
    for _ in range(60):
        source, binary, rgb = sampler.sample()
        linear = spc.srgb_to_linear(from_camera(rgb, source.exposure).permute(1, 2, 0).numpy())
        swap = [f for n, f in FLUX.items() if n != source.name][0]
        ones[source.name].append(binary.mean().item())
        expected[source.name].append(spc.detection_probability(linear * source.flux_scale, source.params).mean())
        other[source.name].append(spc.detection_probability(linear * swap, source.params).mean())
    for name in FLUX:
        n = len(ones[name])
        assert n >= 15  # both scenes drawn
        rate, want, wrong = np.mean(ones[name]), np.mean(expected[name]), np.mean(other[name])
        assert abs(rate - want) < 4 * 0.5 / np.sqrt(n * 16 * 16 * 3)  # within 4 sigma of a Bernoulli mean
        assert abs(rate - wrong) > 0.1
    assert np.mean(ones["gallery"]) > np.mean(ones["orchard"]) + 0.2


def test_seeds_reproduce_and_state_resumes(world):
    a, b, c = _sampler(world, seed=5), _sampler(world, seed=5), _sampler(world, seed=6)
    first = a()
    assert all(torch.equal(x, y) for x, y in zip(first, b()))
    assert not torch.equal(first[1], c()[1])
    state = a.state()
    after = a()
    a2 = _sampler(world, seed=0)
    a2.load(state)
    assert all(torch.equal(x, y) for x, y in zip(after, a2()))
    assert a.describe()["samples"] == 6 and a.describe()["distinct_samples"] == 6
    unpaired = _sampler(world, seed=5, paired=False)()
    assert torch.equal(unpaired[0], first[0]) and not torch.equal(unpaired[1], first[1])


def test_fixed_pairs_exclude_the_validation_views(world, tmp_path):
    rec = augment.augment_scene(
        world / "scenes" / "orchard", world / "spc" / "orchard", tmp_path / "aug", 12, AugmentSettings(), seed=0
    )
    held_out = {f"image{i:03d}" for i in split_views(9)[1]}
    assert not {s["view"] for s in rec["samples"]} & held_out


# --- validation and early stopping -------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ScriptConfig:
    levels: tuple = (0.1, 0.3, 0.45, 0.3, 0.35, 0.2)  # output level after each 2 steps; then the last forever


class Scripted(nn.Module):
    def __init__(self):
        super().__init__()
        self.level = nn.Parameter(torch.zeros(()))
        self.register_buffer("calls", torch.zeros((), dtype=torch.long))


class ScriptedTranslator(base.TranslatorBase):
    """Outputs one grey level everywhere; each training step moves it along a script (a validation
    PSNR the test controls: against a 0.5 grey target it is -20 log10 |level - 0.5|)."""

    multiple = 4

    def __init__(self, cfg, device, vgg_weights=None):
        self.cfg, self.device, self.net = cfg, device, Scripted()
        self.opt = torch.optim.SGD(self.net.parameters(), lr=0.0)

    def modules(self):
        return {"G": self.net}

    def optimizers(self):
        return {"G": self.opt}

    def forward_image(self, binary):
        return torch.zeros_like(binary) + self.net.level

    def train_step(self, binary, rgb):
        with torch.no_grad():
            self.net.calls += 1
            step = int(self.net.calls) - 1
            self.net.level.fill_(self.cfg.levels[min(step // 2, len(self.cfg.levels) - 1)])
        return {"loss": float((self.forward_image(binary) - rgb).abs().mean().detach())}


SCRIPT_PAPER: dict = {}


@pytest.fixture
def scripted(monkeypatch):
    """The scripted translator as a model of the run: its spec (settings from here) and its module."""
    spec = specs.TranslatorSpec(
        "scripted", "Scripted", __name__, config=f"{__name__}:ScriptConfig", paper=f"{__name__}:SCRIPT_PAPER"
    )
    monkeypatch.setitem(specs.TRANSLATORS, "scripted", spec)
    module = types.SimpleNamespace(Config=ScriptConfig, PAPER=SCRIPT_PAPER, Translator=ScriptedTranslator)
    monkeypatch.setitem(translate.MODULES, "scripted", module)
    return "scripted"


def _grey_trainer(world, iterations=40, patience=3):
    """A scripted translator validated every 2 steps against 0.5 grey views."""
    grey = torch.full((3, 8, 12), 0.5)  # shown at exposure CAMERA_WHITE the camera image is the display
    views = [validate.ValidationView(f"grey/{i}", torch.zeros(3, 8, 12), grey, CAMERA_WHITE) for i in range(2)]
    s = train.TrainSettings(iterations=iterations, batch_size=1, crop=8, log_every=2)
    validator = validate.Validator(views, validate.ValidationSettings(every=2, patience=patience), iterations)
    sampler = _sampler(world, crop=8, batch=1)
    return train.TranslatorTrainer(ScriptedTranslator(ScriptConfig(), torch.device("cpu")), sampler, s, validator)


def test_validation_stops_on_a_plateau_and_keeps_the_best(world, tmp_path):
    trainer = _grey_trainer(world)
    ckpt = Checkpoint(tmp_path / "ckpt.pt", {"job": "grey"})
    result = run(trainer, 40, ckpt, CheckpointPolicy(fraction=0, minutes=0))
    # validations at 0 (the untrained start), 2, 4, ..: levels 0 0.1 0.3 0.45 0.3 0.35 0.2: best at
    # step 6, then 3 without a better one
    assert result["stopped_early"] and result["steps"] == 12
    assert trainer.validator.best["step"] == 6
    assert trainer.validator.best["modules"]["G"]["level"] == pytest.approx(0.45)
    assert [h["iteration"] for h in trainer.validator.history] == [0, 2, 4, 6, 8, 10, 12]
    assert [round(h["val_psnr"], 3) for h in trainer.validator.history] == [
        round(-20 * np.log10(abs(v - 0.5)), 3) for v in (0.0, 0.1, 0.3, 0.45, 0.3, 0.35, 0.2)
    ]
    assert float(trainer.model.net.level.detach()) == pytest.approx(0.2)  # the last model is not the kept one
    assert trainer.curve[-1]["iteration"] == 12 and ckpt.record["saves"] == 1  # checkpointed at the stop
    again = _grey_trainer(world)  # resumed from the stop's checkpoint: stops without another step
    rerun = run(again, 40, Checkpoint(tmp_path / "ckpt.pt", {"job": "grey"}))
    assert rerun["resumed_from"] == 12 and rerun["steps"] == 12 and rerun["stopped_early"]
    assert again.validator.best["step"] == 6


def test_a_training_that_only_gets_worse_keeps_its_untrained_start(world):
    """Step 0 is validated like any other: a translator never ends below the start it trained from."""
    trainer = _grey_trainer(world, patience=2)
    trainer.model.cfg = ScriptConfig(levels=(0.2, 0.1, 0.0))  # every step further from the 0.5 target
    with torch.no_grad():
        trainer.model.net.level.fill_(0.45)  # than the start
    result = run(trainer, 40)
    assert result["stopped_early"] and result["steps"] == 4  # two validations (2, 4) without beating step 0
    assert trainer.validator.best["step"] == 0 and trainer.validator.history[0]["iteration"] == 0
    assert trainer.validator.best["modules"]["G"]["level"] == pytest.approx(0.45)
    assert trainer.validator.record()["best_step"] == 0


def test_a_kill_between_the_best_and_the_stop_resumes_the_count(world, tmp_path):
    """Checkpointed at step 8 (best at 6, one validation since), killed at 11: the rerun stops at 12
    with the same history and best model as the uninterrupted run."""
    with pytest.raises(Interrupted):
        run(
            InterruptAt(_grey_trainer(world), 11),
            40,
            Checkpoint(tmp_path / "c.pt", {"job": "grey"}),
            CheckpointPolicy(fraction=0.1, minutes=0),
        )
    resumed, uninterrupted = _grey_trainer(world), _grey_trainer(world)
    result = run(resumed, 40, Checkpoint(tmp_path / "c.pt", {"job": "grey"}))
    run(uninterrupted, 40)
    assert result["resumed_from"] == 8 and result["steps"] == 12 and result["stopped_early"]
    assert resumed.validator.history == uninterrupted.validator.history and resumed.curve == uninterrupted.curve
    assert resumed.validator.best["step"] == 6 and resumed.sampler.state() == uninterrupted.sampler.state()


def test_patience_zero_trains_the_whole_budget(world):
    trainer = _grey_trainer(world, iterations=15, patience=0)
    result = run(trainer, 15)
    assert not result["stopped_early"] and result["steps"] == 15
    assert [h["iteration"] for h in trainer.validator.history][-2:] == [14, 15]  # and at the last step


class StopAfter:
    """A trainer of the generic loop that asks to stop after ``n`` steps (stage 2 trainers have no should_stop)."""

    def __init__(self, n):
        self.n, self.done = n, 0

    def step(self, it):
        self.done = it
        return {"loss": 1.0 / it}

    def should_stop(self):
        return self.done >= self.n

    def state(self):
        return {"done": self.done}

    def load(self, state):
        self.done = state["done"]


def test_the_shared_loop_stops_when_asked(tmp_path):
    result = run(StopAfter(7), 100, Checkpoint(tmp_path / "c.pt", {"k": 1}), CheckpointPolicy(fraction=0.5, minutes=0))
    assert result["steps"] == 7 and result["stopped_early"] and result["checkpoint"]["saves"] == 1
    assert run(StopAfter(10**6), 5)["steps"] == 5


def _online_job(world, tmp_path, method, settings, train_block, **changes):
    """An online-data job validating every 4 steps, its model and checkpoint under ``tmp_path``."""
    job = train.TranslatorJob(
        method,
        train.training_data("online", (), *_dirs(world), {"count": 99, "zoom": [0.9, 1.1]}),
        tmp_path / "model",
        settings,
        train_block,
        seed=1,
        validation={"every": 4, "patience": 2},
        checkpoint=tmp_path / "ckpt.pt",
    )
    return dataclasses.replace(job, **changes)


def test_online_training_records_its_data_and_validation(world, tmp_path, scripted):
    train.train_translator(
        _online_job(world, tmp_path, scripted, {}, {"iterations": 30, "crop": 16, "log_every": 4, "batch_size": 2})
    )
    rec = io.read_json(tmp_path / "model" / "train.json")
    assert rec["data"]["mode"] == "online" and rec["data"]["samples"] == rec["data"]["distinct_samples"]
    assert rec["data"]["training_views"] == 2 * 7 and rec["augment"]["zoom"] == [0.9, 1.1]
    v = rec["validation"]
    assert v["views"] == ["orchard/image000", "orchard/image008", "gallery/image000", "gallery/image008"]
    curve = [h["val_psnr"] for h in v["curve"]]
    best = int(np.argmax(curve))  # the first best: later equal ones are no improvement
    assert v["best_step"] == v["curve"][best]["iteration"] == rec["model_step"]
    assert rec["stopped"]["reason"] == "patience" and rec["stopped"]["step"] == v["best_step"] + 2 * 4
    assert rec["data"]["samples"] == 2 * rec["stopped"]["step"]
    _, model = model_io.load_translator(tmp_path / "model")  # model.pt holds the best model's weights
    assert float(model.net.level.detach()) == pytest.approx(ScriptConfig.levels[min((v["best_step"] - 1) // 2, 5)])
    csv = (tmp_path / "model" / "curve.csv").read_text().splitlines()
    assert csv[0] == "iteration,loss,val_psnr,val_l1" and csv[-1].startswith(f"{rec['stopped']['step']},")
    assert (tmp_path / "model" / "curve.png").stat().st_size > 1000


def test_a_killed_run_resumes_exactly(world, tmp_path, scripted):
    """Killed mid-run (online sampler, validation history, best model and patience in the
    checkpoint), the rerun gives the same record, curve and model as an uninterrupted run."""
    train_block = {"iterations": 20, "crop": 16, "log_every": 4, "batch_size": 2, "decay_from": 0.5}
    full_dir, part_dir = tmp_path / "full", tmp_path / "part"
    full_dir.mkdir(), part_dir.mkdir()
    job = {"method": "restormer", "settings": TINY_RESTORMER, "train_block": train_block}
    no_early_stop = {"validation": {"every": 4, "patience": 0}}
    full = train.train_translator(_online_job(world, full_dir, **job, **no_early_stop))
    part = _online_job(world, part_dir, **job, **no_early_stop)
    setup = train.setup_training(part)
    with pytest.raises(Interrupted):
        run(
            InterruptAt(train.TranslatorTrainer(setup.model, setup.sampler, setup.settings, setup.validator), 13),
            20,
            setup.checkpoint,
            CheckpointPolicy(fraction=0.25, minutes=0),
        )
    resumed = train.train_translator(part)
    assert resumed["checkpoint"]["resumed_from"] == 10 and resumed["checkpoint"]["discarded"] is None
    for key in ("validation", "final_losses", "data", "model_step", "stopped"):
        assert resumed[key] == full[key], key
    assert (part_dir / "model" / "curve.csv").read_text() == (full_dir / "model" / "curve.csv").read_text()
    a, b = (torch.load(d / "model" / "model.pt", weights_only=True)["modules"]["net"] for d in (full_dir, part_dir))
    assert all(torch.equal(a[k], b[k]) for k in a)


TINY_RESTORMER = {"dim": 8, "heads": [1, 1, 1, 1]}


def test_a_held_out_scene_is_validated_whole_and_never_trained_on(world, tmp_path, scripted):
    """hold_out: 1 trains on orchard alone (online samples of its training views only) and validates
    on every view of gallery, which no sample shows; the prior and each validation say per scene."""
    job = _online_job(
        world,
        tmp_path,
        scripted,
        {},
        {"iterations": 8, "crop": 16, "log_every": 4, "batch_size": 2},
        validation={"every": 4, "patience": 0, "hold_out": 1},
    )
    setup = train.setup_training(job)
    assert [src.name for src in setup.sampler.sources] == ["orchard"]
    assert [v.name for v in setup.validator.views] == [f"gallery/image{i:03d}" for i in range(9)]
    rec = train.train_translator(job)
    assert rec["validation"]["hold_out"] == 1 and rec["data"]["training_views"] == 7
    assert rec["training_scenes"] == ["orchard"]
    assert rec["validation"]["views"] == [v.name for v in setup.validator.views]
    assert [h["iteration"] for h in rec["validation"]["curve"]] == [0, 4, 8]
    assert not any(k.startswith("val_psnr:") for k in rec["validation"]["curve"][0])  # one scene: its mean


def test_held_out_scenes_are_scored_each(world):
    """With two held-out scenes each gets its own mean PSNR, and the overall mean is over views."""
    views = validate.load_views(*_dirs(world), frames=1, every_view=True)
    assert len(views) == 18
    grey = lambda b: torch.full_like(b, 0.5)  # noqa: E731
    scores = validate.score(grey, views, per_scene=True)
    per_view = [validate.score(grey, [v])["val_psnr"] for v in views]
    assert scores["val_psnr"] == pytest.approx(np.mean(per_view))
    assert scores["val_psnr:orchard"] == pytest.approx(np.mean(per_view[:9]))
    assert scores["val_psnr:gallery"] == pytest.approx(np.mean(per_view[9:]))
    assert set(validate.score(grey, views)) == {"val_psnr", "val_l1"}


def test_hold_out_leaves_a_scene_to_train_on(world, tmp_path):
    data = train.training_data("online", (), *_dirs(world))
    with pytest.raises(ValueError, match=r"hold_out = 2 keeps every training scene out .*orchard, gallery"):
        train.make_validator(data, {"every": 5, "hold_out": 2}, 1, 10)
    with pytest.raises(ValueError, match="hold_out = -1"):
        validation_settings({"hold_out": -1})
    fixed = train.training_data("fixed", [tmp_path / "a", tmp_path / "b"], *_dirs(world))
    kept, scenes, spc_dirs = fixed.hold_out(1)
    assert kept.augment_dirs == (str(tmp_path / "a"),) and kept.scene_dirs == (str(world / "scenes" / "orchard"),)
    assert scenes == (str(world / "scenes" / "gallery"),) and spc_dirs == (str(world / "spc" / "gallery"),)


def test_fixed_mode_counts_its_distinct_pairs(world, tmp_path):
    augment.augment_scene(
        world / "scenes" / "gallery", world / "spc" / "gallery", tmp_path / "aug", 5, AugmentSettings(), seed=0
    )
    job = train.TranslatorJob(
        "restormer",
        train.training_data("fixed", [tmp_path / "aug"]),
        tmp_path / "model",
        TINY_RESTORMER,
        {"iterations": 3, "crop": 16, "batch_size": 2},
    )
    setup = train.setup_training(job)
    setup.sampler(), setup.sampler()
    assert setup.sampler.describe() == {
        "mode": "fixed",
        "pairs": 5,
        "samples": 4,
        "distinct_samples": int(setup.sampler.seen.sum()),
    }
    assert 1 <= setup.sampler.describe()["distinct_samples"] <= 4 and setup.validator is None


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"mode": "onlin"}, r"stage1\.data = 'onlin': use one of \['fixed', 'online'\]"),
        ({"mode": "online"}, r"stage1\.data = 'online' needs the training scenes' folders"),
        ({"mode": "fixed"}, r"stage1\.data = 'fixed' needs the augmented pairs"),
    ],
)
def test_training_data_errors_name_the_setting(kwargs, match):
    with pytest.raises(ValueError, match=match):
        train.training_data(**kwargs)


def test_validation_settings_are_checked(world, tmp_path):
    with pytest.raises(ValueError, match=r"stage1\.validation: unknown setting\(s\) \['evry'\]; did you mean 'every'"):
        validation_settings({"evry": 3})
    with pytest.raises(ValueError, match="patience = -1"):
        validation_settings({"patience": -1})
    assert validation_settings(None).every == 0
    data = train.training_data("fixed", [tmp_path])
    with pytest.raises(ValueError, match=r"stage1\.validation\.every = 5 needs the training scenes' folders"):
        train.make_validator(data, {"every": 5}, 1, 10)


def test_published_weights_without_training_are_validated_once(world, tmp_path):
    from spc3d.translate import restormer

    tiny = {**TINY_RESTORMER, "prior_sigma": 0.0}  # the published design, as published weights need
    published = restormer.Translator(model_config("restormer", tiny), torch.device("cpu"))
    torch.save({"params": published.net.state_dict()}, tmp_path / "real_denoising.pth")
    settings = {**tiny, "checkpoint": str(tmp_path / "real_denoising.pth")}
    rec = train.train_translator(_online_job(world, tmp_path, "restormer", settings, {"iterations": 0, "crop": 16}))
    assert [h["iteration"] for h in rec["validation"]["curve"]] == [0] and rec["model_step"] == 0
    assert rec["stopped"] == {"step": 0, "of": 0, "reason": "budget"} and rec["data"]["samples"] == 0
    _, loaded = model_io.load_translator(tmp_path / "model")
    assert all(torch.equal(a, b) for a, b in zip(loaded.net.state_dict().values(), published.net.state_dict().values()))
