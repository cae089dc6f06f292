"""The stage-2 stopping rule: when a training objective has stopped improving, and what it records."""

import numpy as np
import pytest

from spc3d import io
from spc3d.inputs.scenes import write_builtin_scene
from spc3d.reconstruct.objectives import BernoulliObjective, RGBObjective
from spc3d.reconstruct.stage2 import ReconstructJob, reconstruct
from spc3d.training import Plateau


def feed(rule: Plateau, values, views=None) -> int | None:
    """Feed per-step values (1-based steps); the step at which the rule stops, or None."""
    for it, v in enumerate(values, 1):
        rule.update(it, v, 0 if views is None else views[it - 1])
        if rule.should_stop():
            return it
    return None


def test_a_steady_decrease_never_stops():
    rule = Plateau(window=10, patience=2, min_gain=0.01)
    assert feed(rule, [0.98**k for k in range(400)]) is None  # ~18 % per window
    assert [it for it, _ in rule.curve] == list(range(10, 401, 10))


def test_a_flat_objective_stops_after_patience_windows_not_before_start():
    values = [1.0 / (1 + k) for k in range(50)] + [0.02] * 200  # falls, then flat from step 51
    # Window 60 (all at 0.02) is still 7 % below window 50; windows 70 and 80 gain nothing.
    assert feed(Plateau(10, 2, 0.01), values) == 80
    assert feed(Plateau(10, 3, 0.01), values) == 90
    assert feed(Plateau(10, 2, 0.01, start=150), values) == 150
    assert feed(Plateau(10, 0, 0.01), values) is None  # patience 0: never


def test_a_small_gain_below_min_gain_counts_as_a_plateau():
    slow = [1.0 * 0.999**k for k in range(300)]  # 1 % per window of 10
    assert feed(Plateau(10, 2, 0.02), slow) == 30  # the first window sets the best; two below 2 %
    assert feed(Plateau(10, 2, 0.005), slow) is None


def test_a_fit_closer_to_its_floor_than_tol_has_nothing_left_to_gain():
    halving = [1e-4 * 0.5 ** (k // 10) for k in range(200)]  # halves every window, forever
    assert feed(Plateau(10, 2, 0.01), halving) is None
    assert feed(Plateau(10, 2, 0.01, tol=1e-5), halving) == 60  # windows 50 and 60 gain 6e-6 and 3e-6


def test_the_mix_of_views_drawn_does_not_look_like_progress():
    """Two views with flat but different losses: a window that happens to draw the easy view more
    often is not an improvement (each view is averaged on its own first)."""
    rng = np.random.default_rng(0)
    views = rng.integers(2, size=400)
    values = np.where(views == 0, 0.1, 0.9)
    assert feed(Plateau(20, 2, 0.01), values, views) == 60
    pooled = Plateau(20, 100, 0.0)
    feed(pooled, values)  # everything as one view: the window means wander with the draw
    assert np.ptp([m for _, m in pooled.curve]) > 0.05


def test_state_round_trip_mid_window_stops_at_the_same_step():
    values = [1.0 / (1 + k) for k in range(30)] + [0.05] * 100
    whole = Plateau(10, 2, 0.01)
    stop = feed(whole, values)
    first = Plateau(10, 2, 0.01)
    feed(first, values[:35])  # stopped mid-window: the partial sums must survive
    resumed = Plateau(10, 2, 0.01)
    resumed.load(first.state())
    for it, v in enumerate(values[35:], 36):
        resumed.update(it, v)
        if resumed.should_stop():
            break
    assert resumed.stopped_at == stop and resumed.curve == whole.curve


@pytest.mark.parametrize(
    "args, word", [((0, 1, 0.01), "window"), ((10, -1, 0.01), "patience"), ((10, 1, 1.0), "min_gain")]
)
def test_bad_rules_are_refused_with_their_values(args, word):
    with pytest.raises(ValueError, match=word):
        Plateau(*args)


def test_the_record_says_where_and_why():
    rule = Plateau(10, 1, 0.01)
    feed(rule, [0.5] * 40)
    rec = rule.record(iterations=100, steps=20)
    assert rec["reason"] == "plateau" and rec["step"] == 20 and rec["of"] == 100
    assert (
        rec["rule"]
        == {"window": 10, "patience": 1, "min_gain": 0.01, "tol": 0.0, "start": 0}
        | {"on": "training objective", "views": []}
        and len(rec["curve"]) == 2
    )
    assert Plateau(10, 1, 0.01).record(100, 100)["reason"] == "budget"


@pytest.fixture(scope="module")
def gallery(tmp_path_factory):
    root = tmp_path_factory.mktemp("plateau") / "gallery"
    write_builtin_scene("gallery", root, height=24, width=32, views=10, supersample=1)
    return root


TINY = {"iterations": 60, "densify_from": 10, "densify_until": 40, "densify_every": 10, "init_points": 200}


def test_a_3dgs_training_stops_on_its_plateau_and_records_it(gallery, tmp_path):
    settings = TINY | {"plateau_window": 10, "plateau_patience": 1, "plateau_gain": 0.9}  # any window < 90 % drop
    settings |= {"densify_from": 5}  # passes at 10 and 20; a stop at 20 skips the pass of its own step
    rec = reconstruct(ReconstructJob(gallery, tmp_path / "r", "gt", "3dgs", settings, checkpoint=tmp_path / "c.pt"))
    train = io.read_json(tmp_path / "r" / "train.json")
    assert train["stopped"]["reason"] == "plateau" and train["stopped"]["step"] == 20 == rec["steps"]
    assert train["stopped"]["of"] == 60 and [s for s, _ in train["stopped"]["curve"]] == [10, 20]
    passes = train["capacity"]["densify"]
    assert [p[0] for p in passes] == [10] and passes[0][-1] == train["capacity"]["gaussians"]
    it, before, cloned, split, pruned, after = passes[0]
    assert after == before + cloned + split - pruned  # a split replaces its parent by two
    again = reconstruct(ReconstructJob(gallery, tmp_path / "r2", "gt", "3dgs", settings, checkpoint=tmp_path / "c.pt"))
    assert again["resumed_from"] == 20 and again["steps"] == 20  # resumed at the stop: no further step


def test_fits_of_the_spad_likelihood_train_to_their_budget(gallery):
    """Most of the Bernoulli NLL is photon noise of unknown size: a relative gain says nothing there."""
    from spc3d.reconstruct import RECONSTRUCTORS
    from spc3d.reconstruct.sources import load_source

    views = load_source("gt", gallery).views
    bern = BernoulliObjective(flux_scale=1e5, q=0.4, exposure_s=1e-4, dark_count_rate=100.0)
    rule = {"plateau_patience": 2}
    grid = {"n_iters": 4, "batch_rays": 64, "n_samples": 8, "res_schedule": [[0, 8]]} | rule
    for model, settings in (("3dgs", TINY | rule), ("nerf-grid", grid)):
        assert RECONSTRUCTORS[model](views, bern, settings, 0)[0].plateau.patience == 0
        assert RECONSTRUCTORS[model](views, RGBObjective(), settings, 0)[0].plateau.patience == 2


def test_observe_mode_trains_to_the_budget_and_keeps_the_stop(gallery, tmp_path):
    settings = {"n_iters": 40, "batch_rays": 128, "n_samples": 8, "res_schedule": [[0, 8]], "chunk": 512}
    settings |= {"plateau_window": 10, "plateau_patience": 1, "plateau_gain": 0.9}
    job = ReconstructJob(gallery, tmp_path / "r", "gt", "nerf-grid", settings, observe_plateau=True)
    rec = reconstruct(job)
    train = io.read_json(tmp_path / "r" / "train.json")
    assert rec["steps"] == 40 and train["at_stop"]["step"] == 20 and train["stopped"]["reason"] == "plateau"
    assert 0 < train["at_stop"]["train_s"] <= train["train_s"]
    names = sorted(p.name for p in (tmp_path / "r" / "renders").iterdir())
    assert (
        names
        == sorted(p.name for p in (tmp_path / "r" / "renders_at_stop").iterdir())
        == ["image000.png", "image008.png"]
    )


def fake_run(tmp_path, combo, seed, psnr, at_stop=None, reason="plateau", views=(), step=600):
    rec = {
        "scene": "courtyard",
        "combination": combo,
        "mean": {"psnr": psnr, "ssim": 0.9},
        "train_s": 10.0,
        "capacity": {"gaussians": 1000},
        "stopped": {"step": step, "of": 1200, "reason": reason, "rule": {"views": list(views)}},
    }
    if at_stop is not None:
        rec["at_stop"] = {"step": 600, "train_s": 4.0, "psnr": at_stop, "ssim": 0.89}
    path = tmp_path / f"{combo}-{seed}.json"
    io.write_json(path, rec)
    return path


def test_stopping_table_pairs_each_fit_and_bounds_only_with_enough_runs(tmp_path):
    from spc3d.evaluation.stopping import stopping_table

    files = [fake_run(tmp_path, "gt+3dgs", s, 30.0 + s, 30.0 + s - 0.1 * (1 + s % 2)) for s in range(6)]
    files += [fake_run(tmp_path, "prior+3dgs", s, 20.0, 20.05, views=("a", "b")) for s in range(2)]
    io.write_json(tmp_path / "toy.json", {"scene": "courtyard", "combination": "toy+mean", "mean": {"psnr": 1.0}})
    files.append(tmp_path / "toy.json")  # a reconstructor without a stopping rule: not a row
    df = stopping_table(files, tmp_path / "stopping").set_index("combination")
    assert list(df.index) == ["gt+3dgs", "prior+3dgs"] and df.loc["gt+3dgs", "n"] == 6
    assert df.loc["gt+3dgs", "ΔPSNR"] == pytest.approx(-0.15) and df.loc["gt+3dgs", "time saved"] == pytest.approx(0.6)
    assert df.loc["gt+3dgs", "ΔPSNR lo"] == pytest.approx(-0.2) and df.loc["gt+3dgs", "ΔPSNR hi"] < 0
    assert not np.isfinite(df.loc["prior+3dgs", "ΔPSNR lo"])  # 2 runs: no test can bound it
    md = (tmp_path / "stopping.md").read_text()
    assert "6/6" in md and "50% of 1200" in md and "n < 6: unbounded" in md and "−" not in md.split("\n")[0]
    assert df.loc["gt+3dgs", "judged on"] == "training loss" and "2 held-out training views" in md
    assert (tmp_path / "stopping.tex").read_text().count("$\\Delta$") >= 1


def test_a_rule_that_fires_on_the_last_step_did_not_stop_early(tmp_path):
    from spc3d.evaluation.stopping import stopping_table

    files = [fake_run(tmp_path, "none-x1+nerf-grid", s, 20.0, step=1200 if s else 900) for s in range(3)]
    df = stopping_table(files, tmp_path / "stopping").set_index("combination")
    assert df.loc["none-x1+nerf-grid", "stopped early"] == "1/3"


# --- the rule judged on training views held out of the fit (plateau_views) ----------------------


def test_closing_windows_directly_is_the_same_rule():
    values = [1.0, 0.5, 0.4, 0.399, 0.398, 0.397]
    fed, closed = Plateau(10, 2, 0.01), Plateau(10, 2, 0.01)
    feed(fed, np.repeat(values, 10))
    for k, v in enumerate(values, 1):
        closed.close(10 * k, v)
        if closed.should_stop():
            break
    assert np.allclose(closed.curve, fed.curve) and closed.stopped_at == fed.stopped_at == 50


def test_hold_out_spreads_the_views_inside_the_set_and_keeps_three_quarters(gallery):
    from spc3d.reconstruct.sources import load_source
    from spc3d.reconstruct.views import hold_out

    views = load_source("gt", gallery).views  # 10 views, 2 of them scored: 8 training views
    fit, check = hold_out(views, 2)
    assert check.names == [views.names[2], views.names[6]] and len(fit.names) == 6
    assert not set(fit.names) & set(check.names)
    assert (check.targets[1] == views.targets[6]).all() and np.allclose(check.cameras.w2c[0], views.cameras.w2c[2])
    assert hold_out(views, 0) == (views, None)
    assert hold_out(views, 7)[1].names == check.names  # at most a quarter of the views
    few = views.subset(range(3))
    assert hold_out(few, 2)[1] is None and hold_out(few, 2)[0] is few
    with pytest.raises(ValueError, match="plateau_views = -1: .* must be >= 0"):
        hold_out(views, -1)


def noise_views(views, seed=0):
    """The views with each target replaced by independent noise: nothing one view says about another."""
    from spc3d.reconstruct.views import Views

    rng = np.random.default_rng(seed)
    import torch

    noise = torch.as_tensor(rng.uniform(0.0, 1.0, views.targets.shape).astype(np.float32))
    return Views(noise, views.cameras, views.names)


@pytest.mark.parametrize("model", ["3dgs", "nerf-grid"])
def test_held_out_views_stop_a_fit_learning_noise_while_its_training_loss_still_falls(gallery, model):
    """Targets that are independent noise per view: the fit memorises its own views (training loss
    falls) but predicts nothing of a view it never saw, so the held-out rule stops it at once."""
    from spc3d.reconstruct import RECONSTRUCTORS
    from spc3d.reconstruct.sources import load_source

    views = noise_views(load_source("gt", gallery).views)
    rule = {"plateau_patience": 2, "plateau_gain": 0.01, "plateau_window": 10}
    grid = {"n_iters": 200, "batch_rays": 256, "n_samples": 16, "res_schedule": [[0, 16]], "chunk": 1024}
    settings = (TINY | {"iterations": 200} if model == "3dgs" else grid) | rule
    held, _, _ = RECONSTRUCTORS[model](views, RGBObjective(), settings | {"plateau_views": 2}, 0)
    train, _, _ = RECONSTRUCTORS[model](views, RGBObjective(), settings, 0)
    assert len(held.views.names) == 6 and held.plateau.views == [views.names[2], views.names[6]]
    stops = {}
    for name, trainer in (("held", held), ("train", train)):
        losses = []
        for it in range(1, 201):
            losses.append(trainer.step(it)["loss"])
            if trainer.should_stop():
                break
        stops[name] = (it, np.mean(losses[:10]), np.mean(losses[-10:]))
    assert stops["held"][0] <= 60 and stops["held"][2] < stops["held"][1]  # stopped while the fit still fell
    assert stops["train"][0] > stops["held"][0]


def test_the_held_out_value_is_the_objective_on_those_views(gallery):
    import torch

    from spc3d.reconstruct import RECONSTRUCTORS
    from spc3d.reconstruct.sources import load_source

    views = load_source("gt", gallery).views
    trainer, _, _ = RECONSTRUCTORS["3dgs"](views, RGBObjective(), TINY | {"plateau_views": 2, "plateau_window": 5}, 0)
    for it in range(1, 6):
        trainer.step(it)
    with torch.no_grad():
        ref = [
            trainer.objective.loss(
                trainer.model.render(trainer.check.cameras, j, trainer.background)["image"], trainer.check.targets[j]
            ).item()
            for j in range(2)
        ]
    assert trainer.plateau.curve == [(5, pytest.approx(float(np.mean(ref)), rel=1e-6))]


def test_a_job_records_the_views_that_judged_its_stop(gallery, tmp_path):
    settings = TINY | {"plateau_window": 10, "plateau_patience": 1, "plateau_gain": 0.9, "plateau_views": 2}
    reconstruct(ReconstructJob(gallery, tmp_path / "r", "gt", "3dgs", settings))
    train = io.read_json(tmp_path / "r" / "train.json")
    rule = train["stopped"]["rule"]
    assert rule["on"] == "held-out training views" and len(rule["views"]) == 2
    assert train["train_views"] == 6 and train["stopped"]["reason"] == "plateau"
