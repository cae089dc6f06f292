"""Adding a model family is its code and its spec: a toy translator and a toy reconstructor, defined
here and registered from here (``SPC3D_PLUGINS`` names this file; :mod:`spc3d.specs`), run
through the smoke DAG from training to the tables, with no edit to the package.

The toys are real models, only small: a 3x3 convolution as a residual over the physics prior, and
a reconstructor that learns one colour per pixel of the mean training view (it renders every
novel view the same, so it scores like a blurred mean image, but it trains, checkpoints and
renders through the same contract as 3DGS).
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch
from torch import nn

TOY_TRANSLATOR, TOY_RECONSTRUCTOR = "toy", "toy-mean"


# --- the toy translator (the contract of spc3d.translate.base) ----------------------------------


@dataclass(frozen=True)
class Config:
    width: int = 3  # channels of the convolution (the sweeps' width knob sets it)
    prior_sigma: float = 2.0  # a residual over the physics prior, like the default translators
    lr: float = 1e-3


PAPER: dict = {}


def _translator_base():
    from spc3d.translate.base import TranslatorBase, adam

    class Translator(TranslatorBase):
        paired, multiple = True, 1

        def __init__(self, cfg: Config, device, vgg_weights=None):
            self.cfg, self.device = cfg, torch.device(device)
            self.net = nn.Conv2d(3, 3, 3, padding=1).to(self.device)
            self.make_prior(cfg.prior_sigma, head=self.net)
            self.opt = adam(self.net.parameters(), self.device, lr=cfg.lr)

        def modules(self):
            return self.with_prior({"net": self.net})

        def optimizers(self):
            return {"opt": self.opt}

        def forward_image(self, binary):
            return self.plus_prior(self.net(binary), binary, signed=False).clamp(0.0, 1.0)

        def train_step(self, binary, rgb):
            self.opt.zero_grad()
            loss = (self.forward_image(binary) - rgb).abs().mean()
            loss.backward()
            self.opt.step()
            return {"loss": float(loss)}

    return Translator


def __getattr__(name):  # Translator is built on first use, so registering imports no torch module of spc3d
    if name == "Translator":
        return _translator_base()
    raise AttributeError(name)


# --- the toy reconstructor (the contract of spc3d.training.run and spc3d.reconstruct.stage2) ----


@dataclass(frozen=True)
class MeanConfig:
    iterations: int = 30
    lr: float = 0.05


class MeanImageTrainer:
    """One learnt colour per pixel, fitted to every training view: the mean image."""

    def __init__(self, views, objective, cfg: MeanConfig, seed: int):
        torch.manual_seed(seed)
        self.views, self.objective, self.cfg = views, objective, cfg
        self.image = nn.Parameter(torch.full(views.targets.shape[1:], 0.5))
        self.opt = torch.optim.Adam([self.image], lr=cfg.lr)

    def step(self, it: int) -> dict[str, float]:
        self.opt.zero_grad()
        pred = self.image.expand_as(self.views.targets)
        loss = self.objective.loss(pred, self.views.targets)
        loss.backward()
        self.opt.step()
        return {"loss": float(loss)}

    def render(self, cameras, j: int):
        return self.objective.to_srgb(self.image.detach())

    def capacity(self) -> dict:
        return {"parameters": self.image.numel()}

    def state(self) -> dict:
        return {"image": self.image.detach().clone(), "opt": self.opt.state_dict()}

    def load(self, state: dict) -> None:
        with torch.no_grad():
            self.image.copy_(state["image"])
        self.opt.load_state_dict(state["opt"])


def mean_config(settings: dict) -> MeanConfig:
    from spc3d.specs.build import build_config

    return build_config(MeanConfig, settings, f"stage2.{TOY_RECONSTRUCTOR}")


def make_mean(views, objective, settings: dict, seed: int, points=None):
    from spc3d.reconstruct.objectives import RGBObjective

    cfg = mean_config(settings)
    return MeanImageTrainer(views, objective or RGBObjective("mse"), cfg, seed), cfg.iterations, cfg


# --- the registration (called by spc3d.specs when SPC3D_PLUGINS names this file) ----------------


def spc3d_register(register):
    from spc3d.specs import ReconstructorSpec, TranslatorSpec

    here = str(Path(__file__).resolve())
    register(TranslatorSpec(TOY_TRANSLATOR, "Toy (3x3 conv)", here, width_field="width"))
    register(
        ReconstructorSpec(TOY_RECONSTRUCTOR, "Toy mean image", f"{here}:make_mean", f"{here}:mean_config", "iterations")
    )


# --- the tests ------------------------------------------------------------------------------------


def plugin_env() -> dict:
    return dict(os.environ, SPC3D_PLUGINS=str(Path(__file__).resolve()))


def test_a_plugin_registers_both_families_in_a_fresh_process():
    """The registries, names and knobs all see the toys; the built-in models stay as they were."""
    import subprocess

    code = (
        "import sys; sys.path.insert(0, 'workflow');"
        "from spc3d import names; from spc3d.sweeps.budget import WIDTH_KEYS, ITERATION_FIELD;"
        "from spc3d.translate import MODULES; from spc3d.reconstruct import RECONSTRUCTORS;"
        "from spc3d.specs.reconstructors import reconstructor_config; from spc3d.specs.translators import model_config;"
        f"assert names.STAGE1_METHODS[-1] == '{TOY_TRANSLATOR}' and names.STAGE2_MODELS[-1] == '{TOY_RECONSTRUCTOR}';"
        f"assert WIDTH_KEYS['{TOY_TRANSLATOR}'] == 'width' and ITERATION_FIELD['{TOY_RECONSTRUCTOR}'] == 'iterations';"
        f"assert MODULES['{TOY_TRANSLATOR}'].Config().width == 3;"
        f"assert model_config('{TOY_TRANSLATOR}', {{'width': 5}}) == MODULES['{TOY_TRANSLATOR}'].Config(width=5);"
        f"assert reconstructor_config('{TOY_RECONSTRUCTOR}', {{'iterations': 7}}).iterations == 7;"
        f"print(names.LABELS['{TOY_TRANSLATOR}'], sorted(RECONSTRUCTORS))"
    )
    repo = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code], cwd=repo, env=plugin_env(), capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "Toy (3x3 conv) ['3dgs', 'nerf-grid', 'nerf-mlp', 'toy-mean']"


def test_a_plugin_on_the_old_names_still_loads_with_a_warning():
    """spc3d.models (the specs' old module) and spc3d.training.build_config (the builder's old home)
    still answer, each with a DeprecationWarning naming the new place, and hand out the same objects."""
    import subprocess
    import warnings

    code = (
        "import sys, warnings; sys.path.insert(0, 'workflow'); warnings.simplefilter('always');"
        "from spc3d import specs\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always'); import spc3d.models as old\n"
        "assert old.TRANSLATORS is specs.TRANSLATORS and old.TranslatorSpec is specs.TranslatorSpec\n"
        "print(caught[0].category.__name__, caught[0].message)"
    )
    repo = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code], cwd=repo, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("DeprecationWarning spc3d.models is now spc3d.specs"), out.stdout
    from spc3d import training
    from spc3d.specs import build

    with pytest.warns(DeprecationWarning, match=r"spc3d\.training\.build_config is now spc3d\.specs\.build"):
        assert training.build_config is build.build_config
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(AttributeError, match="no attribute 'build_configs'"):
            training.build_configs  # noqa: B018


def test_register_refuses_a_clash_and_a_bad_name():
    from spc3d import specs

    with pytest.raises(ValueError, match="already registered"):
        specs.register(specs.TranslatorSpec("pix2pix", "again", "spc3d.translate.pix2pix"))
    with pytest.raises(ValueError, match="must match"):
        specs.register(specs.TranslatorSpec("toy-net", "a dash ends a source name", "x"))
    with pytest.raises(ValueError, match="defines no spc3d_register"):
        specs.load_plugins(str(Path(specs.__file__)))


@pytest.mark.slow
def test_toy_models_run_through_the_smoke_dag(smoke_run):
    """The session's smoke run carries the toys (conftest.TOY_COMBINATIONS): trained, reconstructed,
    scored and in the tables, beside the built-in models."""
    from conftest import TOY_COMBINATIONS

    assert smoke_run.built["full_rc"] == 0, smoke_run.built["full_err"]
    res = smoke_run.work / "results"
    for combo in TOY_COMBINATIONS:
        metrics = json.loads((res / "eval" / "courtyard" / combo / "metrics.json").read_text())
        assert metrics["mean"]["psnr"] > 5.0, (combo, metrics["mean"])
    record = json.loads((res / "recon" / "courtyard" / "toy+toy-mean" / "train.json").read_text())
    assert record["capacity"]["parameters"] == 48 * 64 * 3 and record["iterations"] == MeanConfig().iterations
    model = json.loads((res / "models" / TOY_TRANSLATOR / "train.json").read_text())
    assert model["iterations"] == 4 and model["settings"]["width"] == 3  # stage1.train of the smoke preset
    two_stage = (res / "tables" / "two_stage.csv").read_text()
    assert all(combo in two_stage for combo in TOY_COMBINATIONS)
    assert "Toy (3x3 conv)" in (res / "tables" / "stage1.csv").read_text()
