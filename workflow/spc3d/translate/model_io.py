"""A stage-1 model folder: building a method's translator, writing what a training leaves, loading it back.

``build_translator`` builds a method's Translator from its Config (resolved from its settings by
:func:`spc3d.specs.translators.model_config`); ``check_pretrained`` loads published weights early.
``write_model_folder`` writes a trained translator's folder (``results/models/{method}/``, atomically):

    model.pt      the kept networks (every module's state) + method name + resolved Config + the
                  domain of their outputs (``camera``: :mod:`.camera`)
    train.json    the training's record (:func:`spc3d.translate.train.train_translator`)
    curve.csv     the losses every ``log_every`` iterations and the validation PSNR / L1
    curve.png     the training curve (:mod:`.curves`)

and ``load_translator`` reads ``model.pt`` back, ready for ``translate`` (no loss networks).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import pandas as pd
import torch

from spc3d import io
from spc3d.specs import settings_classes
from spc3d.specs.build import build_config
from spc3d.specs.translators import model_config
from spc3d.training import default_device
from spc3d.translate import MODULES
from spc3d.translate.camera import DOMAIN
from spc3d.translate.curves import plot_curve


def check_pretrained(method: str, settings: dict) -> None:
    """Load the published weights of ``settings['checkpoint']`` into the method's network now (safely:
    no pickled code runs), so a corrupt or mismatched file stops the run before any job."""
    cfg = model_config(method, settings)
    build_translator(method, cfg, torch.device("cpu")).load_pretrained(settings["checkpoint"])


def build_translator(method: str, cfg, device: torch.device, vgg_weights: dict | None = None):
    return MODULES[method].Translator(cfg, device, vgg_weights=vgg_weights)


def write_model_folder(out_dir, model, record: dict, curve: list[dict], modules: dict | None = None) -> None:
    """model.pt (``modules``: the weights to keep, e.g. the best validated; default: the model's
    current ones), train.json, curve.csv (losses and validation by iteration) and curve.png."""
    modules = modules or {k: m.state_dict() for k, m in model.modules().items()}
    validation = (record.get("validation") or {}).get("curve", [])
    frame = pd.DataFrame(curve)
    if validation:
        scores = pd.DataFrame(validation)
        frame = frame.merge(scores, on="iteration", how="outer").sort_values("iteration") if curve else scores
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        tmp = Path(tmp)
        tmp.mkdir(parents=True, exist_ok=True)
        saved = {"method": record["method"], "config": record["settings"], "modules": modules, "domain": DOMAIN}
        torch.save(saved, tmp / "model.pt")
        io.write_json(tmp / "train.json", record)
        io.write_text(tmp / "curve.csv", frame.to_csv(index=False, float_format="%.6g"))
        plot_curve(frame, tmp / "curve.png", record["method"], record.get("model_step"))


def load_translator(model_dir: str | os.PathLike, device: torch.device | None = None):
    """A trained model from ``model_dir/model.pt``, ready for ``translate`` (no loss networks)."""
    path = Path(model_dir) / "model.pt"
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: train the method first (rule train_translator)")
    saved = io.load_torch(path, "trained stage-1 model")
    if saved.get("domain") != DOMAIN:
        raise ValueError(
            f"{path} was trained to output display images, not camera images (spc3d.translate.camera): it "
            f"predates the exposure-aware display; delete {Path(model_dir)} so the workflow trains it again"
        )
    method = saved["method"]
    cfg = build_config(settings_classes(method)[0], saved["config"], f"{path} config")
    if any(f.name == "vgg_loss" for f in dataclasses.fields(cfg)):
        cfg = dataclasses.replace(cfg, vgg_loss=False)  # the perceptual loss is a training-only network
    model = build_translator(method, cfg, device or default_device())
    for k, m in model.modules().items():
        m.load_state_dict(saved["modules"][k])
    return method, model
