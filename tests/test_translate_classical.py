"""The ``classical`` stage-1 method (spc3d.translate.classical): the binomial VST and its inverse,
every candidate denoiser against the true detection probability, the Gaussian candidate as the
``prior`` method, the selection on the training scenes, model.pt round trips, setting errors, the
training job's record and the denoiser benchmark."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from spc3d import specs
from spc3d.specs.translators import model_config
from spc3d.translate import MODULES, blurred_mle, classical, model_io
from spc3d.translate.classical import DENOISERS, GRID, P_MAX, Config, Translator, inverse_vst, vst, vst_sigma

from conftest import load_script

CPU = torch.device("cpu")
RUNNABLE = [i for i, (name, _) in enumerate(GRID) if not classical.unavailable(name)]
BENCHMARK = Path(__file__).resolve().parents[1] / "benchmarks" / "classical_denoisers.py"

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def bernoulli(p: np.ndarray, frames: int = 1, seed: int = 0) -> np.ndarray:
    """The mean of ``frames`` Bernoulli(p) frames."""
    rng = np.random.default_rng(seed)
    return rng.binomial(frames, p).astype(np.float64) / frames


def blocks(h: int = 48, w: int = 64) -> np.ndarray:
    """A piecewise-constant detection probability (H, W, 3): four blocks, another level per channel."""
    p = np.empty((h, w, 3))
    for c, levels in enumerate(((0.2, 0.6, 0.4, 0.8), (0.3, 0.7, 0.5, 0.1), (0.5, 0.2, 0.8, 0.4))):
        p[: h // 2, : w // 2, c], p[: h // 2, w // 2 :, c], p[h // 2 :, : w // 2, c], p[h // 2 :, w // 2 :, c] = levels
    return p


def pairs_of(n: int = 4, size=(24, 32), seed: int = 0) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """(binary, sRGB) training pairs whose targets are the images the bits were drawn from."""
    g = torch.Generator().manual_seed(seed)
    out = []
    for _ in range(n):
        rgb = torch.rand(3, 1, 1, generator=g).expand(3, *size) * 0.6 + 0.2
        out.append(((torch.rand(3, *size, generator=g) < rgb).float(), rgb.clone()))
    return out


def pinned(name: str, **params) -> Translator:
    return Translator(Config(choice=name, params=params or None), CPU)


def test_the_registry_treats_it_as_an_untrained_method():
    spec = specs.TRANSLATORS["classical"]
    assert not spec.trained and spec.width_field is None and not Translator.trainable
    assert classical.PAPER == {} and 15 <= len(GRID) <= 25 and set(DENOISERS) == {n for n, _ in GRID}
    for name, module in MODULES.items():  # the spec's flag and the model's agree for every method
        assert specs.TRANSLATORS[name].trained == module.Translator.trainable, name


@pytest.mark.parametrize("frames", [1, 4, 16])
def test_the_vst_and_its_inverse_round_trip(frames):
    p = np.linspace(0.0, 1.0, 101)
    np.testing.assert_allclose(inverse_vst(vst(p, frames), frames), np.minimum(p, P_MAX), atol=1e-12)
    k = np.arange(frames + 1) / frames  # the levels a K-frame mean takes
    np.testing.assert_allclose(inverse_vst(vst(k, frames), frames), np.minimum(k, P_MAX), atol=1e-12)
    assert vst_sigma(frames) == pytest.approx(1 / (2 * np.sqrt(frames + 0.5)))


def test_the_vst_stabilises_binomial_noise_at_its_sigma():
    """At K = 16 the VST's output has the std it promises, whatever p (away from 0 and 1)."""
    for p in (0.2, 0.5, 0.8):
        y = vst(bernoulli(np.full(40000, p), 16, seed=1), 16)
        assert y.std() == pytest.approx(vst_sigma(16), rel=0.06)


@pytest.mark.parametrize("index", RUNNABLE, ids=[classical.label(i) for i in RUNNABLE])
def test_every_candidate_brings_a_noisy_frame_closer_to_its_detection_probability(index):
    name, params = GRID[index]
    p = blocks()
    x = bernoulli(p, 1, seed=index)
    out = DENOISERS[name](x, 1, **params)
    assert out.shape == x.shape and out.min() >= 0 and out.max() <= 1 + 1e-6  # detection() clamps to P_MAX
    assert np.mean((out - p) ** 2) < 0.5 * np.mean((x - p) ** 2)


def test_translate_keeps_the_shape_and_range():
    x = torch.from_numpy(np.stack([bernoulli(blocks(20, 26), seed=s) for s in (1, 2)])).permute(0, 3, 1, 2).float()
    for name, params in (("tv", {"weight": 1.0}), ("nlm", dict(GRID[5][1])), ("gaussian", {"sigma": 2.0})):
        model = pinned(name, **params)
        model.net.gain.fill_(0.3)
        y = model.translate(x)
        assert y.shape == x.shape and y.dtype == torch.float32 and 0 <= y.min() and y.max() <= 1


def test_the_gaussian_candidate_is_the_prior_method():
    """Pinned at the prior's blur, ``classical`` fits the same gain on the same pairs and outputs
    exactly what ``prior`` does."""
    pairs = pairs_of(6)
    ours, prior = pinned("gaussian", sigma=2.0), blurred_mle.Translator(blurred_mle.Config(prior_sigma=2.0), CPU)
    table = ours.fit_untrained(lambda: iter(pairs), None)
    assert prior.fit_untrained(lambda: iter(pairs), None) is None
    assert table["pinned"] and table["chosen"] == "gaussian(sigma=2.0)" and "candidates" not in table
    torch.testing.assert_close(ours.net.gain, prior.prior.gain, rtol=0, atol=0)
    x = torch.stack([b for b, _ in pairs])
    torch.testing.assert_close(ours.translate(x), prior.translate(x), rtol=0, atol=0)


def test_the_search_keeps_the_best_validation_score():
    """The chosen candidate is the one ``validate`` scores best; every searched one is in the table."""
    model = Translator(Config(denoisers=("gaussian", "tv")), CPU)
    target = next(i for i, (n, p) in enumerate(GRID) if n == "tv" and p["weight"] == 0.75)

    def validate(translate):
        translate(pairs_of(1)[0][0][None])
        return {"val_psnr": 30.0 if int(model.net.choice) == target else 20.0, "val_l1": 0.1}

    table = model.fit_untrained(lambda: iter(pairs_of(8)), validate)
    assert int(model.net.choice) == target and table["chosen"] == "tv(weight=0.75)" and not table["pinned"]
    assert [r["index"] for r in table["candidates"]] == [i for i, (n, _) in enumerate(GRID) if n in ("gaussian", "tv")]
    assert table["calibration"] == "1 training pair in 4 (2 pairs)" and "held-out views" in table["scored_on"]
    assert all(r["ms_per_image"] > 0 and len(r["gain"]) == 3 for r in table["candidates"])


def test_without_validation_the_search_scores_the_calibration_pairs():
    """Flat images: the widest blur wins among the Gaussians (known best), scored on the pairs."""
    model = Translator(Config(denoisers=("gaussian",), calibration_every=1), CPU)
    table = model.fit_untrained(lambda: iter(pairs_of(3, size=(32, 32))), None)
    psnrs = [r["val_psnr"] for r in table["candidates"]]
    assert psnrs == sorted(psnrs) and table["chosen"] == "gaussian(sigma=3.0)"
    assert "calibration pairs" in table["scored_on"]


def test_a_fitted_model_survives_its_folder(tmp_path):
    model = Translator(Config(denoisers=("tv",), frames=4), CPU)
    model.fit_untrained(lambda: iter(pairs_of(4)), None)
    record = {"method": "classical", "settings": dataclasses.asdict(model.cfg)}
    model_io.write_model_folder(tmp_path / "m", model, record, [])
    method, loaded = model_io.load_translator(tmp_path / "m", CPU)
    assert method == "classical" and loaded.cfg.frames == 4
    assert int(loaded.net.choice) == int(model.net.choice) >= 0 and torch.equal(loaded.net.gain, model.net.gain)
    x = pairs_of(1)[0][0][None]
    assert torch.equal(loaded.translate(x), model.translate(x))
    state = model.net.state_dict()
    state["grid"] = state["grid"] + 1
    with pytest.raises(ValueError, match="another candidate grid"):
        Translator(Config(), CPU).net.load_state_dict(state)


def test_settings_errors_name_the_setting():
    with pytest.raises(ValueError, match=r"stage1\.classical: denoisers = \['bm4d'\].*unknown denoiser \['bm4d'\]"):
        model_config("classical", {"denoisers": ["bm4d"]})
    with pytest.raises(ValueError, match=r"stage1\.classical: .*choice = 'median'.*choose from"):
        model_config("classical", {"choice": "median"})
    with pytest.raises(ValueError, match=r"params = \{'sigma': 7\.0\}: not one candidate.*gaussian\(sigma=2\.0\)"):
        model_config("classical", {"choice": "gaussian", "params": {"sigma": 7.0}})
    with pytest.raises(ValueError, match=r"stage1\.classical\.frames: .*stage1\.frames"):
        model_config("classical", {"frames": 4})
    assert model_config("classical", {}, frames=4).frames == 4  # the job's K
    with pytest.raises(RuntimeError, match="no denoiser chosen yet"):
        Translator(Config(), CPU).translate(torch.zeros(1, 3, 8, 8))


# --- the training job and the benchmark, on two tiny training scenes ----------------------------------


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """results/{scenes,spc,augment}/{tabletop,orchard}: 9 views each (2 held out), 3 pairs each."""
    from spc3d.inputs.augment import AugmentSettings, augment_scene
    from spc3d.inputs.build import simulate_scene
    from spc3d.inputs.scenes import write_builtin_scene
    from spc3d.physics import spc

    root = tmp_path_factory.mktemp("classical")
    for name in ("tabletop", "orchard"):
        write_builtin_scene(name, root / "scenes" / name, height=24, width=32, views=9, supersample=1)
        simulate_scene(root / "scenes" / name, root / "spc" / name, spc.SPCParams(frames=2), seed=0)
        augment_scene(root / "scenes" / name, root / "spc" / name, root / "augment" / name, 3, AugmentSettings(), 0)
    return root


def test_the_training_job_records_the_selection(world, tmp_path):
    from spc3d.translate.train import TranslatorJob, train_translator, training_data

    scenes = ("tabletop", "orchard")
    data = training_data(
        "fixed", [world / "augment" / s for s in scenes], [world / "scenes" / s for s in scenes],
        [world / "spc" / s for s in scenes],
    )  # fmt: skip
    settings = {"denoisers": ["gaussian", "tv"], "calibration_every": 2}
    job = TranslatorJob(
        "classical", data, tmp_path / "m", settings, {"iterations": 5, "crop": 16}, frames=2, validation={}
    )
    rec = train_translator(job)
    selection = rec["selection"]
    assert rec["iterations"] == 0 and rec["settings"]["frames"] == 2 and rec["prior"] is None
    assert len(selection["candidates"]) == 9 and "held-out views" in selection["scored_on"]
    best = max(selection["candidates"], key=lambda r: r["val_psnr"])
    assert selection["chosen"] == best["candidate"] and rec["validation"]["best_step"] == 0
    _, model = model_io.load_translator(tmp_path / "m", CPU)
    assert int(model.net.choice) == best["index"] and model.cfg.frames == 2
    assert model.net.gain.tolist() == pytest.approx(selection["gain"])


def test_the_benchmark_compares_the_denoisers_on_the_held_out_views(world, capsys):
    bench = load_script(BENCHMARK)
    bench.main(["--results", str(world), "--scenes", "tabletop", "orchard", "--families", "gaussian", "tv"])
    out = capsys.readouterr().out
    assert "4 held-out views of tabletop, orchard" in out and "SSIM" in out and "ms / image" in out
    assert "gaussian(sigma=2.0)" in out and "tv(weight=1.5)" in out and "best:" in out
    with pytest.raises(SystemExit, match="is missing"):
        bench.main(["--results", str(world), "--scenes", "gallery"])
