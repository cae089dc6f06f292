"""The no-reference score of novel views: held-out photons explained by a render (spc3d.evaluation.heldout)."""

import dataclasses

import numpy as np
import pytest

from spc3d.evaluation.heldout import heldout_photon_score
from spc3d.physics import sensors, spc

PARAMS = dataclasses.replace(spc.SPCParams(), frames=64)
SCALE = 8.0e4  # photons/s at linear 1


def scene_views(n=3, shape=(24, 32), seed=0):
    rng = np.random.default_rng(seed)
    base = rng.random((n,) + shape + (3,))
    return [np.clip(v, 0.05, 0.95) for v in base]  # sRGB views


def held_out(views, pattern, seed=1):
    """Fractions of ones of PARAMS.frames frames per view as ``pattern`` records them (None: RGB)."""
    rng = np.random.default_rng(seed)
    out = []
    for v in views:
        frames = spc.simulate_frames(v.astype(np.float32), SCALE, PARAMS, rng)
        if pattern is not None:
            phi = spc.flux_from_srgb(v, SCALE)
            frames = sensors.sensor_frames(frames, pattern, phi, PARAMS, rng)
        out.append(frames.mean(0, dtype=np.float64))
    return out


@pytest.mark.parametrize("cfa", [None, "RGGB", "mono", "RGBW"])
def test_the_true_views_explain_their_photons_best(cfa):
    pattern = None if cfa is None else sensors.cfa_pattern(cfa)
    views = scene_views()
    frac = held_out(views, pattern)
    truth = heldout_photon_score(views, frac, PARAMS.frames, PARAMS, pattern)
    # The fitted gain recovers the exposure the photons were drawn at (a few % at 64 frames).
    assert truth["gain_fitted"] == pytest.approx(SCALE, rel=0.05)
    assert truth["excess_nll"] >= 0 and truth["floor_nll"] > 0
    blurred = [np.full_like(v, v.mean((0, 1))) for v in views]  # colour right, structure gone
    shuffled = views[1:] + views[:1]  # the wrong views
    for worse in (blurred, shuffled):
        assert heldout_photon_score(worse, frac, PARAMS.frames, PARAMS, pattern)["excess_nll"] > truth["excess_nll"]


def test_exposure_does_not_change_the_score():
    """A render that is right up to a global gain (in linear light) scores the same: the gain is fitted."""
    views = scene_views()
    frac = held_out(views, None)
    dim = [spc.linear_to_srgb(0.5 * spc.srgb_to_linear(v)) for v in views]
    a = heldout_photon_score(views, frac, PARAMS.frames, PARAMS)
    b = heldout_photon_score(dim, frac, PARAMS.frames, PARAMS)
    assert b["excess_nll"] == pytest.approx(a["excess_nll"], abs=1e-5)
    assert b["gain_fitted"] == pytest.approx(2 * a["gain_fitted"], rel=1e-3)


def test_extreme_and_masked_pixels_stay_finite():
    """Pixels that never or always fired, black and white renders, hot pixels masked: finite scores."""
    pattern = sensors.cfa_pattern("RGGB")
    frac = [np.zeros((8, 8)), np.ones((8, 8))]
    renders = [np.zeros((8, 8, 3)), np.ones((8, 8, 3))]
    valid = np.ones((8, 8), bool)
    valid[3, 4] = False
    out = heldout_photon_score(renders, frac, 16, PARAMS, pattern, valid)
    assert np.isfinite(out["excess_nll"]) and out["measurements"] == 2 * 63 and out["floor_nll"] == 0.0


def test_mismatched_inputs_are_named():
    with pytest.raises(ValueError, match="renders for"):
        heldout_photon_score([np.zeros((4, 4, 3))], [], 4, PARAMS)
    with pytest.raises(ValueError, match="does not match"):
        heldout_photon_score([np.zeros((4, 4, 3))], [np.zeros((4, 5, 3))], 4, PARAMS)
