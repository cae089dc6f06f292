"""The native splat kernels on degenerate inputs: no crash, no out-of-bounds access, finite results.

numba does no bounds checking, so a NaN that reaches the integer arithmetic of a kernel (a box
corner, a tile index) writes wherever it points: NaN in the poses once ended a 3DGS job with
SIGSEGV. Here every case of a table (NaN / ±inf / huge / tiny / zero / negative values in each
Gaussian parameter, empty and 1x1 images, no Gaussians, all behind the camera, Gaussians covering
the image; bad cameras and shapes) runs forward and backward on the float32 SIMD and the float64
kernels, on 1 and 2 threads, in a subprocess (a segfault then fails the case that caused it, not
pytest). Each case must

* finish with finite image, alpha and gradients;
* treat a Gaussian with any non-finite parameter as absent: the image, alpha and every other
  gradient equal those of the scene without it (bit for bit), and its own gradients are zero;
* or, for a bad camera / size / shape, raise a ValueError that names the value.

One more run repeats the table with ``NUMBA_BOUNDSCHECK=1`` (every kernel recompiled with bounds
checks, cached in pytest's cache folder) and asserts that no index was out of range.

Run by hand: ``python tests/test_splat_robust.py --threads 2 [case ...]`` prints one JSON line
per case and dtype.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

try:
    import fcntl
except ImportError:  # not POSIX: each pytest-xdist worker runs the table itself
    fcntl = None

NAN, INF = math.nan, math.inf
H, W = 24, 32
DTYPES = ("float32", "float64")  # float32 RGB: SIMD kernels; float64: the float64 kernels


# ---------------------------------------------------------------- the table


def _scene(n: int = 200, seed: int = 0, height: int = H, width: int = W) -> dict:
    """3-D Gaussians in front of a slightly rotated camera (leaf values, float64)."""
    g = torch.Generator().manual_seed(seed)
    z = 2 + 4 * torch.rand(n, generator=g, dtype=torch.float64)
    xy = (torch.rand(n, 2, generator=g, dtype=torch.float64) - 0.5) * 1.2 * z[:, None]
    c, s = math.cos(0.2), math.sin(0.2)
    w2c = torch.tensor([[c, 0, s, 0.05], [0, 1, 0, -0.1], [-s, 0, c, 0.2]], dtype=torch.float64)
    return {
        "means": torch.cat([xy, z[:, None]], 1),
        "scales": 0.02 + 0.1 * torch.rand(n, 3, generator=g, dtype=torch.float64),
        "quats": torch.randn(n, 4, generator=g, dtype=torch.float64),
        "opacities": torch.sigmoid(1.5 * torch.randn(n, generator=g, dtype=torch.float64)),
        "colors": torch.rand(n, 3, generator=g, dtype=torch.float64),
        "camera": dict(w2c=w2c, fx=30.0, fy=28.0, cx=width / 2 - 0.3, cy=height / 2, height=height, width=width),
    }


def _screen(n: int = 200, seed: int = 1, height: int = H, width: int = W) -> dict:
    """Screen-space Gaussians for the rasterizer alone (leaf values, float64)."""
    g = torch.Generator().manual_seed(seed)
    sig = 0.5 + 2.5 * torch.rand(n, 2, generator=g, dtype=torch.float64)
    ang = math.pi * torch.rand(n, generator=g, dtype=torch.float64)
    cos, sin = torch.cos(ang), torch.sin(ang)
    a = (cos * sig[:, 0]) ** 2 + (sin * sig[:, 1]) ** 2
    c = (sin * sig[:, 0]) ** 2 + (cos * sig[:, 1]) ** 2
    b = cos * sin * (sig[:, 0] ** 2 - sig[:, 1] ** 2)
    det = a * c - b * b
    return {
        "means2d": torch.rand(n, 2, generator=g, dtype=torch.float64) * torch.tensor([width, height]),
        "conics": torch.stack([c / det, -b / det, a / det], -1),
        "opacities": 0.05 + 0.9 * torch.rand(n, generator=g, dtype=torch.float64),
        "colors": torch.rand(n, 3, generator=g, dtype=torch.float64),
        "depths": torch.rand(n, generator=g, dtype=torch.float64),
        "radii": torch.ceil(3 * sig.max(1).values).int(),
        "height": height,
        "width": width,
    }


IDX = [0, 7, 50, 199]  # the Gaussians a case sets (first, last, and in different chunks / tiles)


def _set(key, value, cols=None, idx=IDX):
    def edit(d):
        t = d[key]
        if cols is None:
            t[idx] = value
        else:
            for col in cols:
                t[idx, col] = value
        return d

    return edit


def _mixed(d: dict, keys: dict) -> dict:
    """Every 10th Gaussian gets one of a list of bad values, cycling over parameters and values
    (huge: ``keys[name]`` if given, else 1e30)."""
    for k, i in enumerate(range(3, len(d[next(iter(keys))]), 10)):
        key = list(keys)[k % len(keys)]
        bad = [NAN, INF, -INF, keys[key] or 1e30, 1e-30, 0.0, -1.0]
        d[key][i, ...] = bad[(k // len(keys)) % len(bad)]
    return d


# name -> (kind, build): kind "scene" (projection + rasterizer), "screen" (rasterizer), or
# "error" (build raises; the third entry: words the ValueError must contain)
CASES: dict[str, tuple] = {}
for key, cols in (
    ("means", (0,)),
    ("means", (2,)),
    ("scales", (1,)),
    ("quats", (0, 1, 2, 3)),
    ("opacities", None),
    ("colors", (1,)),
):
    for label, value in (
        ("nan", NAN),
        ("inf", INF),
        ("-inf", -INF),
        ("huge", 1e30),
        ("tiny", 1e-30),
        ("zero", 0.0),
        ("negative", -1.0),
    ):
        col = "" if cols is None or len(cols) > 1 else f"[{cols[0]}]"
        CASES[f"scene {key}{col} {label}"] = (
            "scene",
            lambda key=key, cols=cols, value=value: _set(key, value, cols)(_scene()),
        )
CASES.update(
    {
        "scene means all 1e30": ("scene", lambda: _set("means", 1e30)(_scene())),
        "scene means at the camera centre": ("scene", lambda: _set("means", 0.0)(_scene())),
        "scene scales huge (cover the image)": ("scene", lambda: _set("scales", 1e30, idx=slice(None))(_scene(40))),
        "scene scales 100 (cover the image)": ("scene", lambda: _set("scales", 100.0, idx=slice(None))(_scene(40))),
        "scene all NaN": (
            "scene",
            lambda: {**_scene(60), **{k: torch.full_like(v, NAN) for k, v in _scene(60).items() if k != "camera"}},
        ),
        "scene all behind the camera": (
            "scene",
            lambda: (lambda d: (d["means"].__setitem__((slice(None), 2), -d["means"][:, 2]), d)[1])(_scene()),
        ),
        "scene no Gaussians": ("scene", lambda: _scene(0)),
        "scene image 1x1": (
            "scene",
            lambda: {
                **_scene(50, height=1, width=1),
                "camera": {**_scene(1)["camera"], "height": 1, "width": 1, "fx": 1.0, "fy": 1.0, "cx": 0.5, "cy": 0.5},
            },
        ),
        "scene 5000 mixed (all threads)": (
            "scene",
            lambda: _mixed(_scene(5000, seed=3), {"means": 0, "scales": 0, "quats": 0, "opacities": 0, "colors": 0}),
        ),
        "screen means2d nan": ("screen", lambda: _set("means2d", NAN, (0,))(_screen())),
        "screen means2d inf": ("screen", lambda: _set("means2d", INF, (1,))(_screen())),
        "screen means2d -inf": ("screen", lambda: _set("means2d", -INF, (0, 1))(_screen())),
        "screen means2d huge": ("screen", lambda: _set("means2d", 1e30, (0,))(_screen())),
        "screen conics nan": ("screen", lambda: _set("conics", NAN, (1,))(_screen())),
        "screen conics inf": ("screen", lambda: _set("conics", INF, (0,))(_screen())),
        "screen conics zero": ("screen", lambda: _set("conics", 0.0)(_screen())),
        "screen conics negative": ("screen", lambda: _set("conics", -1.0, (0, 2))(_screen())),
        "screen conics overflow (NaN exponents)": (
            "screen",
            lambda: (
                lambda d: (
                    d["conics"].__setitem__(IDX, torch.tensor([3e38, -3e38, 3e38], dtype=torch.float64)),
                    d["radii"].__setitem__(IDX, 40),
                    d,
                )[2]
            )(_screen()),
        ),
        "screen radii huge": ("screen", lambda: _set("radii", 2**31 - 1)(_screen())),
        "screen radii negative": ("screen", lambda: _set("radii", -5)(_screen())),
        "screen opacities nan": ("screen", lambda: _set("opacities", NAN)(_screen())),
        "screen opacities inf": ("screen", lambda: _set("opacities", INF)(_screen())),
        "screen opacities 1e7": ("screen", lambda: _set("opacities", 1e7)(_screen())),
        "screen no Gaussians": ("screen", lambda: _screen(0)),
        "screen image 1x1": ("screen", lambda: _screen(30, height=1, width=1)),
        "screen depths nan": ("screen", lambda: _set("depths", NAN)(_screen())),
        "screen depths -inf": ("screen", lambda: _set("depths", -INF)(_screen())),
        "screen colors inf": ("screen", lambda: _set("colors", INF, (2,))(_screen())),
        "screen 5000 mixed (all threads)": (
            "screen",
            lambda: _mixed(
                _screen(5000, seed=4), {"means2d": 0, "conics": 0, "opacities": 1e5, "colors": 0, "depths": 0}
            ),
        ),
    }
)


def _camera_case(**change):
    def build():
        d = _scene(20)
        cam = dict(d["camera"])
        for k, v in change.items():
            if k == "w2c":
                cam["w2c"] = cam["w2c"].clone()
                cam["w2c"][v[0]] = v[1]
            else:
                cam[k] = v
        d["camera"] = cam
        return d

    return build


for name, change, words in (
    ("w2c nan", {"w2c": ((1, 3), NAN)}, ("w2c", "nan", "row 1, column 3")),
    ("w2c inf", {"w2c": ((0, 0), INF)}, ("w2c", "inf", "row 0, column 0")),
    ("fx nan", {"fx": NAN}, ("fx = nan",)),
    ("fx inf", {"fx": INF}, ("fx = inf",)),
    ("fx zero", {"fx": 0.0}, ("fx = 0.0", "> 0")),
    ("fx negative", {"fx": -30.0}, ("fx = -30.0", "> 0")),
    ("fy zero", {"fy": 0.0}, ("fy = 0.0",)),
    ("cx nan", {"cx": NAN}, ("cx = nan",)),
    ("cy -inf", {"cy": -INF}, ("cy = -inf",)),
    ("height zero", {"height": 0}, ("height=0",)),
    ("width negative", {"width": -4}, ("width=-4",)),
    ("width float", {"width": 32.5}, ("width=32.5",)),
):
    CASES[f"camera {name}"] = ("error", _camera_case(**change), words)
CASES.update(
    {
        "rasterize image 0x5": ("error", lambda: {**_screen(10), "height": 0, "width": 5}, ("height=0",)),
        "rasterize colors rows": (
            "error",
            lambda: {**_screen(10), "colors": torch.rand(9, 3, dtype=torch.float64)},
            ("colors", "(9, 3)"),
        ),
        "rasterize background nan": (
            "error",
            lambda: {**_screen(10), "background": torch.tensor([0.0, NAN, 0.0])},
            ("background", "nan"),
        ),
        "rasterize background size": ("error", lambda: {**_screen(10), "background": torch.zeros(2)}, ("background",)),
        "project quats shape": (
            "error",
            lambda: {**_scene(10), "quats": torch.rand(10, 3, dtype=torch.float64)},
            ("quats", "(10, 3)"),
        ),
    }
)


# ---------------------------------------------------------------- running one case


def _leaves(d: dict, keys, dtype) -> dict:
    return {k: d[k].to(dtype).detach().clone().requires_grad_() for k in keys}


SCENE_KEYS = ("means", "scales", "quats", "opacities", "colors")
SCREEN_KEYS = ("means2d", "conics", "opacities", "colors")


def _render(kind: str, d: dict, dtype, keep=None) -> tuple[list, dict]:
    """Image, alpha and the leaves (with gradients of a fixed random linear loss) of a case;
    ``keep``: render only these Gaussians."""
    from spc3d.reconstruct.splat import project_gaussians_native, rasterize_native

    if keep is not None:
        d = {k: (v[keep] if torch.is_tensor(v) and v.dim() and k not in ("background",) else v) for k, v in d.items()}
    bg = d.get("background", torch.tensor([0.2, 0.4, 0.6])).to(dtype)
    if kind == "scene":
        p = _leaves(d, SCENE_KEYS, dtype)
        cam = d["camera"]
        proj = project_gaussians_native(p["means"], p["scales"], p["quats"], **cam)
        args = (proj.means2d, proj.conics, p["opacities"], p["colors"], proj.depths, proj.radii)
        height, width = cam["height"], cam["width"]
    else:
        p = _leaves(d, SCREEN_KEYS, dtype)
        args = (p["means2d"], p["conics"], p["opacities"], p["colors"], d["depths"].to(dtype), d["radii"])
        height, width = d["height"], d["width"]
    image, alpha = rasterize_native(*args, height, width, bg)
    g = torch.Generator().manual_seed(5)
    w_img = torch.randn(image.shape, generator=g, dtype=torch.float64).to(image.dtype)
    w_alpha = torch.randn(alpha.shape, generator=g, dtype=torch.float64).to(alpha.dtype)
    ((image * w_img).sum() + (alpha * w_alpha).sum()).backward()
    return [image.detach(), alpha.detach()], p


def _bad_rows(kind: str, d: dict) -> torch.Tensor:
    """(N,) the Gaussians with a non-finite parameter (they must act as absent)."""
    keys = SCENE_KEYS if kind == "scene" else (*SCREEN_KEYS, "depths")
    n = len(d[keys[0]])
    bad = torch.zeros(n, dtype=torch.bool)
    for k in keys:
        fin = torch.isfinite(d[k])
        bad |= ~(fin.all(1) if fin.dim() > 1 else fin)
    return bad


def run_case(name: str, dtype_name: str) -> str:
    """'ok' or what went wrong."""
    entry = CASES[name]
    kind, build = entry[:2]
    dtype = getattr(torch, dtype_name)
    d = build()
    if kind == "error":
        try:
            _render("scene" if "camera" in d else "screen", d, dtype)
        except ValueError as e:
            missing = [w for w in entry[2] if w not in str(e)]
            return "ok" if not missing else f"ValueError without {missing}: {e}"
        return "no ValueError"
    outs, leaves = _render(kind, d, dtype)
    problems = [f"{n} not finite" for n, t in (("image", outs[0]), ("alpha", outs[1])) if not torch.isfinite(t).all()]
    problems += [f"d{k} not finite" for k, t in leaves.items() if not torch.isfinite(t.grad).all()]
    bad = _bad_rows(kind, {k: v.to(dtype) if torch.is_tensor(v) and v.is_floating_point() else v for k, v in d.items()})
    if bad.any() and not problems:
        problems += [f"d{k} of a non-finite Gaussian is not 0" for k, t in leaves.items() if t.grad[bad].any()]
        ref_outs, ref_leaves = _render(kind, d, dtype, keep=~bad)
        problems += [
            f"{n} differs without the non-finite Gaussians"
            for n, a, b in zip(("image", "alpha"), outs, ref_outs)
            if not torch.equal(a, b)
        ]
        problems += [
            f"d{k} differs without the non-finite Gaussians"
            for k in leaves
            if not torch.equal(leaves[k].grad[~bad], ref_leaves[k].grad)
        ]
    op = d["opacities"][torch.isfinite(d["opacities"])]
    if kind == "screen" and not problems and not (op > 1e6).any():
        # the reference back-end draws the same (it culls alike); not for opacities > e^20 / 255
        # (far outside [0, 1]): the reference composites those at its exponent floor, e^-20 (the
        # native kernels skip exponents below it)
        from spc3d.reconstruct.splat import rasterize_reference

        with torch.no_grad():
            ref = rasterize_reference(
                *(leaves[k].detach() for k in SCREEN_KEYS),
                d["depths"].to(dtype),
                d["radii"],
                d["height"],
                d["width"],
                torch.tensor([0.2, 0.4, 0.6], dtype=dtype),
            )
        problems += [
            f"{n} differs from the reference by {(a - b).abs().max():.2e}"
            for n, a, b in zip(("image", "alpha"), outs, ref)
            if not ((a - b).abs() <= 1e-5 * (1 + b.abs())).all()
        ]
    return "ok" if not problems else "; ".join(problems)


def main(argv=None) -> None:
    """Subprocess entry: runs the named cases (all when none) and prints a JSON line per case."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("cases", nargs="*")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    for name in args.cases or list(CASES):
        for dt in DTYPES:
            print(json.dumps({"begin": name, "dtype": dt}), flush=True)
            try:
                result = run_case(name, dt)
            except Exception as e:  # noqa: BLE001 - reported to the parent
                result = f"raised {type(e).__name__}: {e}"
            print(json.dumps({"case": name, "dtype": dt, "result": result}), flush=True)


# ---------------------------------------------------------------- the tests

_RESULTS: dict = {}


def _run_cases(threads: int, env: dict | None = None, timeout: int = 300) -> dict:
    """{(case, dtype): result} for all cases in subprocesses; a case that kills its process (a
    segfault) is reported with the signal, and the remaining cases run in a fresh one."""
    results, todo = {}, list(CASES)
    # OpenMP workers that sleep instead of spinning between regions: the same kernels and thread
    # counts, 3x less CPU on a busy machine (the other pytest worker runs beside this one)
    env = {"OMP_WAIT_POLICY": "PASSIVE", **(os.environ if env is None else env)}
    while todo:
        proc = subprocess.run(
            [sys.executable, __file__, "--threads", str(threads), *todo],
            capture_output=True,
            text=True,
            timeout=timeout,
            env=env,
            cwd=Path(__file__).resolve().parents[1],
        )
        current = None
        for line in proc.stdout.splitlines():
            if not line.startswith("{"):
                continue
            msg = json.loads(line)
            if "begin" in msg:
                current = (msg["begin"], msg["dtype"])
            else:
                results[(msg["case"], msg["dtype"])] = msg["result"]
                current = None
        if current is None:
            if proc.returncode != 0:
                raise AssertionError(f"case runner failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
            break
        results[current] = f"process died (exit {proc.returncode}) in this case:\n{proc.stderr[-1500:]}"
        todo = todo[todo.index(current[0]) + (current[1] == DTYPES[-1]) :]
        if current[1] != DTYPES[-1]:  # the other dtype of the crashed case still runs
            todo = todo[1:]
            results[(current[0], DTYPES[-1])] = "not run (the process died in the other dtype)"
    return results


def _results(threads: int, shared: Path | None) -> dict:
    """The table's results on ``threads``, computed once per test session: with pytest-xdist the
    first worker to ask runs the cases and the others read its file (under a lock)."""
    if threads in _RESULTS:
        return _RESULTS[threads]
    run_id = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if shared is None or run_id is None or fcntl is None:
        _RESULTS[threads] = _run_cases(threads)
        return _RESULTS[threads]
    path = shared / f"splat_robust_{run_id}_{threads}.json"
    with open(path.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not path.exists():
            rows = [[case, dt, result] for (case, dt), result in _run_cases(threads).items()]
            path.write_text(json.dumps(rows))
        _RESULTS[threads] = {(case, dt): result for case, dt, result in json.loads(path.read_text())}
    return _RESULTS[threads]


@pytest.fixture(scope="session")
def shared_folder(tmp_path_factory) -> Path:
    """A folder shared by the pytest-xdist workers of this session."""
    return tmp_path_factory.getbasetemp().parent


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("case", list(CASES))
def test_degenerate_input(case, threads, shared_folder):
    """Forward + backward of one table case (float32 SIMD and float64 kernels) on ``threads``."""
    res = _results(threads, shared_folder)
    failed = {dt: res.get((case, dt), "no result") for dt in DTYPES if res.get((case, dt)) != "ok"}
    assert not failed, f"{case} on {threads} thread(s): {failed}"


def test_no_out_of_bounds_access_with_numba_boundscheck(request):
    """The whole table with every kernel compiled with bounds checks (NUMBA_BOUNDSCHECK=1): no
    IndexError, and the same verdicts. Compiled once into pytest's cache folder (slow the first
    time: every kernel is compiled again)."""
    cache = getattr(request.config, "cache", None)
    folder = cache.mkdir("spc3d_numba_boundscheck") if cache is not None else None
    env = dict(os.environ, NUMBA_BOUNDSCHECK="1")
    if folder is not None:
        env["NUMBA_CACHE_DIR"] = str(folder)
    res = _run_cases(2, env=env, timeout=600)
    index_errors = {k: v for k, v in res.items() if "IndexError" in v or "out of bounds" in v}
    assert not index_errors, index_errors
    failed = {k: v for k, v in res.items() if v != "ok"}
    assert not failed, failed


def _trainer(**changes):
    """A 3DGS trainer on three 24x32 views of random targets, 200 Gaussians (one thread)."""
    import numpy as np

    from spc3d.cameras import Cameras, look_at
    from spc3d.reconstruct.gaussians import GaussianConfig
    from spc3d.reconstruct.objectives import RGBObjective
    from spc3d.reconstruct.splatting import SplatTrainer
    from spc3d.reconstruct.views import Views

    w2c = np.stack([look_at(np.array([x, 0.0, -4.0]), np.zeros(3)) for x in (-0.5, 0.0, 0.5)])
    cams = Cameras(w2c, np.tile([30.0, 30.0, 16.0, 12.0], (3, 1)), H, W, np.tile([1.0, 8.0], (3, 1)))
    g = torch.Generator().manual_seed(0)
    views = Views(torch.rand(3, H, W, 3, generator=g), cams, ["a", "b", "c"])
    cfg = GaussianConfig(**{"iterations": 20, "densify_every": 5, "densify_from": 100, "sh_interval": 1000, **changes})
    points = torch.randn(200, 3, generator=g).numpy() * 0.5
    return SplatTrainer(views, RGBObjective("l1", 0.2), cfg, seed=0, points=points, colors=np.full((200, 3), 0.5))


def test_trainer_stops_on_a_non_finite_loss_naming_the_iteration(one_thread):
    t = _trainer()
    for it in (1, 2):
        t.step(it)
    t.views.targets[:, 3, 4, 1] = NAN  # e.g. a corrupt image: every Gaussian would turn NaN
    before = t.model.means.detach().clone()
    with pytest.raises(FloatingPointError, match=r"iteration 3: the loss on training view \d is nan"):
        t.step(3)
    assert torch.equal(t.model.means, before)  # stopped before the update


def test_trainer_stops_when_no_gaussian_is_finite(one_thread):
    t = _trainer()
    t.step(1)
    with torch.no_grad():
        t.model.means[:, 0] = NAN  # all non-finite: nothing is drawn, the loss stays finite
    for it in range(2, 5):
        t.step(it)  # not drawn, zero gradient: the rest of the model is left alone
    assert torch.isfinite(t.model.log_scales).all()
    with pytest.raises(FloatingPointError, match="iteration 5: none of the 200 Gaussians"):
        t.step(5)


def test_trainer_names_the_camera_it_cannot_render(one_thread):
    from spc3d.reconstruct.splat.project import CameraError

    t = _trainer()
    t.views.cameras.intrinsics[1, 0] = NAN
    t.render(t.views.cameras, 0)
    with pytest.raises(CameraError, match=r"camera 1 \(of 3\): fx = nan, must be finite and > 0"):
        t.render(t.views.cameras, 1)
    t.views.cameras.w2c[:, 2, 3] = INF
    with pytest.raises(CameraError, match=r"camera \d \(of 3\): w2c .* inf at row 2, column 3"):
        t.step(1)


def test_crash_in_a_case_is_reported_and_the_rest_still_run(monkeypatch):
    """The case runner itself: a case whose process dies is named, the others still get results."""
    # the parent lists the cases; the subprocess builds its own table, told through the environment
    monkeypatch.setattr(
        sys.modules[__name__], "CASES", {"scene means[0] nan": CASES["scene means[0] nan"], "zz crashes": None}
    )
    res = _run_cases(1, env=dict(os.environ, SPC3D_ROBUST_TEST_ABORT="zz crashes"))
    assert res[("scene means[0] nan", "float32")] == "ok"
    assert "process died" in res[("zz crashes", "float32")]


if os.environ.get("SPC3D_ROBUST_TEST_ABORT"):  # test_crash_in_a_case_is_reported_and_the_rest_still_run
    CASES[os.environ["SPC3D_ROBUST_TEST_ABORT"]] = ("scene", lambda: os.abort())


if __name__ == "__main__":
    main()
