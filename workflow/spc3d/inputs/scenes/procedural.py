"""Procedural textures: deterministic patterns made from seeded noise (no file, no download).

They widen the content of the built-in scenes beyond scikit-image's 19 photographs, so that the
training and evaluation layouts can each have their own materials (see
:data:`spc3d.inputs.scenes.textures.TRAIN_SOURCES` / ``EVAL_SOURCES``). Each pattern returns a linear
RGB image (h, w, 3) float64 in [0, 1]; the same name always gives the same image.

    marble, wood, weave                                      training materials
    cobbles, masonry, tiles, foliage, glazing, pegboard,     evaluation materials
    books, carpet
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


def value_noise(h: int, w: int, cells: int, rng: np.random.Generator) -> np.ndarray:
    """(h, w) noise in [0, 1]: random values on a (cells + 1)^2 lattice, smoothstep-interpolated."""
    lattice = rng.random((cells + 1, cells + 1))
    y, x = (np.arange(h) + 0.5) * cells / h, (np.arange(w) + 0.5) * cells / w
    y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
    fy, fx = y - y0, x - x0
    fy, fx = fy * fy * (3 - 2 * fy), fx * fx * (3 - 2 * fx)  # smoothstep: no creases at cell edges
    a, b = lattice[y0][:, x0], lattice[y0][:, x0 + 1]
    c, d = lattice[y0 + 1][:, x0], lattice[y0 + 1][:, x0 + 1]
    top, bottom = a + (b - a) * fx[None], c + (d - c) * fx[None]
    return top + (bottom - top) * fy[:, None]


def fbm(h: int, w: int, rng: np.random.Generator, cells: int = 4, octaves: int = 5) -> np.ndarray:
    """(h, w) fractal noise in [0, 1]: octaves of value noise, each twice as fine and half as strong."""
    total, norm = np.zeros((h, w)), 0.0
    for k in range(octaves):
        total += 0.5**k * value_noise(h, w, cells * 2**k, rng)
        norm += 0.5**k
    return total / norm


def mix(a, b, t: np.ndarray) -> np.ndarray:
    """Per-pixel blend of colours ``a`` -> ``b`` by t (h, w) in [0, 1] -> (h, w, 3)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a + (b - a) * t[..., None]


def _grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (y, x) in [0, 1), each (h, w)."""
    return np.meshgrid((np.arange(h) + 0.5) / h, (np.arange(w) + 0.5) / w, indexing="ij")


def marble(h: int, w: int) -> np.ndarray:
    """White stone with grey-blue veins: a sine of x bent by fractal turbulence."""
    rng = np.random.default_rng(11)
    y, x = _grid(h, w)
    veins = np.abs(np.sin(np.pi * (3.0 * x + 1.5 * y + 5.0 * fbm(h, w, rng, cells=3))))
    return mix((0.28, 0.3, 0.36), (0.86, 0.84, 0.8), veins**0.35) * (0.9 + 0.1 * fbm(h, w, rng, cells=16))[..., None]


def wood(h: int, w: int) -> np.ndarray:
    """Planks of growth rings: distance from an off-centre axis, perturbed, folded into rings."""
    rng = np.random.default_rng(12)
    y, x = _grid(h, w)
    r = np.hypot((x - 0.3) * 2.2, (y + 0.8) * 0.5) + 0.06 * fbm(h, w, rng, cells=4)
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * 14.0 * r)
    grain = fbm(h, w, rng, cells=32, octaves=3)
    return mix((0.18, 0.08, 0.03), (0.55, 0.3, 0.12), 0.7 * rings**2 + 0.3 * grain)


def weave(h: int, w: int) -> np.ndarray:
    """Basket-weave cloth: warp and weft threads crossing over and under in a two-colour twill."""
    rng = np.random.default_rng(13)
    y, x = _grid(h, w)
    n = 24
    cy, cx = np.floor(y * n).astype(int), np.floor(x * n).astype(int)
    warp_on_top = (cx + cy) % 4 < 2
    across = np.where(warp_on_top, np.sin(np.pi * (x * n % 1.0)), np.sin(np.pi * (y * n % 1.0)))
    colour = np.where(
        warp_on_top[..., None],
        mix((0.05, 0.12, 0.35), (0.12, 0.25, 0.6), across),
        mix((0.35, 0.06, 0.04), (0.7, 0.2, 0.1), across),
    )
    return colour * (0.85 + 0.15 * fbm(h, w, rng, cells=8))[..., None]


def cobbles(h: int, w: int) -> np.ndarray:
    """Rounded stones set in sand: Voronoi cells (F2 - F1 distance for the joints), one tone each."""
    rng = np.random.default_rng(21)
    y, x = _grid(h, w)
    seeds = rng.random((48, 2))
    d = np.hypot(y[..., None] - seeds[:, 0], x[..., None] - seeds[:, 1])  # (h, w, S)
    part = np.partition(d, 1, axis=-1)
    joint = np.clip((part[..., 1] - part[..., 0]) / 0.025, 0.0, 1.0)
    tone = rng.random(len(seeds))[np.argmin(d, axis=-1)]
    stone = mix((0.2, 0.19, 0.17), (0.5, 0.46, 0.4), tone) * (0.75 + 0.25 * fbm(h, w, rng, cells=16))[..., None]
    sand = np.array([0.42, 0.34, 0.22])
    return sand + (stone - sand) * np.sqrt(joint)[..., None]  # sand in the joints, stone inside


def masonry(h: int, w: int) -> np.ndarray:
    """Ashlar wall: staggered courses of long dressed blocks with pale mortar, each block its own tone."""
    rng = np.random.default_rng(22)
    y, x = _grid(h, w)
    rows = 6
    row = np.floor(y * rows).astype(int)
    shift = 0.5 * (row % 2) + 0.17 * (row % 3)
    u = x * 3.0 + shift
    col = np.floor(u).astype(int)
    fu, fv = u - col, y * rows - row
    mortar = (np.minimum(fu, 1 - fu) < 0.02) | (np.minimum(fv, 1 - fv) < 0.05)
    tone = rng.random((rows + 1, 8))[row, col % 8]
    block = mix((0.45, 0.38, 0.3), (0.72, 0.62, 0.48), tone) * (0.8 + 0.2 * fbm(h, w, rng, cells=12))[..., None]
    return np.where(mortar[..., None], np.array([0.78, 0.76, 0.7]), block)


def tiles(h: int, w: int) -> np.ndarray:
    """Glazed square tiles, terracotta and blue in a random mix, with dark grout."""
    rng = np.random.default_rng(23)
    y, x = _grid(h, w)
    n = 8
    fy, fx = y * n % 1.0, x * n % 1.0
    grout = (np.minimum(fy, 1 - fy) < 0.04) | (np.minimum(fx, 1 - fx) < 0.04)
    pick = rng.random((n, n))[np.floor(y * n).astype(int), np.floor(x * n).astype(int)]
    glaze = np.where((pick < 0.35)[..., None], np.array([0.08, 0.2, 0.55]), np.array([0.62, 0.22, 0.1]))
    shine = 0.85 + 0.15 * fbm(h, w, rng, cells=6)
    return np.where(grout[..., None], np.array([0.12, 0.11, 0.1]), glaze * shine[..., None])


def foliage(h: int, w: int) -> np.ndarray:
    """Dense leaves: a few hundred pointed leaves of varied greens, each with a midrib, over shadow."""
    rng = np.random.default_rng(24)
    y, x = _grid(h, w)
    out = mix((0.01, 0.03, 0.01), (0.04, 0.09, 0.02), fbm(h, w, rng, cells=8))  # shade between leaves
    greens = np.array([[0.06, 0.22, 0.03], [0.14, 0.38, 0.05], [0.3, 0.5, 0.08], [0.08, 0.3, 0.12], [0.4, 0.45, 0.1]])
    for _ in range(420):  # painter's order: later leaves lie on top
        cy, cx = rng.random(2)
        length, angle = rng.uniform(0.05, 0.11), rng.uniform(0.0, np.pi)
        r = int(np.ceil(length * max(h, w))) + 1
        rows = slice(max(0, int(cy * h) - r), min(h, int(cy * h) + r + 1))
        cols = slice(max(0, int(cx * w) - r), min(w, int(cx * w) + r + 1))
        dy, dx = y[rows, cols] - cy, x[rows, cols] - cx
        along = (dx * np.cos(angle) + dy * np.sin(angle)) / length  # -1 .. 1 tip to tip
        across = (-dx * np.sin(angle) + dy * np.cos(angle)) / length
        half_width = 0.38 * np.sqrt(np.clip(1.0 - along**2, 0.0, 1.0)) * (1.0 - 0.3 * along)  # lanceolate
        leaf = np.abs(across) < half_width
        colour = greens[rng.integers(len(greens))] * rng.uniform(0.7, 1.3)
        lit = (0.75 + 0.25 * along - 0.4 * np.abs(across) / np.maximum(half_width, 1e-6))[..., None]
        rib = (np.abs(across) < 0.03)[..., None]
        shade = np.where(rib, colour * 1.5 + 0.04, colour * lit)
        out[rows, cols] = np.where(leaf[..., None], shade, out[rows, cols])
    return out


def glazing(h: int, w: int) -> np.ndarray:
    """Greenhouse glass seen from inside: white glazing bars (4 x 3 panes), pale sky through the
    upper panes, blurred green growth through the lower ones, a little condensation everywhere."""
    rng = np.random.default_rng(25)
    y, x = _grid(h, w)
    sky = mix((0.55, 0.7, 0.82), (0.85, 0.9, 0.92), fbm(h, w, rng, cells=3) ** 1.5)
    growth = mix((0.08, 0.2, 0.05), (0.3, 0.45, 0.15), fbm(h, w, rng, cells=6))
    horizon = 0.55 + 0.12 * (fbm(h, w, rng, cells=2)[0:1] - 0.5)  # a ragged line of plants outside
    view = np.where((y > horizon)[..., None], growth, sky)
    mist = 0.15 * fbm(h, w, rng, cells=24, octaves=3)[..., None]
    panes = view * (0.85 - mist) + mist * 0.9
    fx, fy = x * 4 % 1.0, y * 3 % 1.0
    bar = (np.minimum(fx, 1 - fx) < 0.025) | (np.minimum(fy, 1 - fy) < 0.02)
    return np.where(bar[..., None], np.array([0.82, 0.84, 0.8]), panes)


def pegboard(h: int, w: int) -> np.ndarray:
    """Tool-wall hardboard: fibrous brown board drilled with a regular grid of dark holes."""
    rng = np.random.default_rng(26)
    y, x = _grid(h, w)
    fibre = fbm(h, w, rng, cells=48, octaves=3)
    board = mix((0.32, 0.2, 0.1), (0.5, 0.34, 0.18), 0.6 * fibre + 0.4 * fbm(h, w, rng, cells=4))
    n = 16
    fy, fx = y * n % 1.0 - 0.5, x * n % 1.0 - 0.5
    r = np.hypot(fx, fy)
    hole = np.clip((r - 0.13) / 0.03, 0.0, 1.0)  # 0 in the hole, 1 on the board (anti-aliased rim)
    rim = 1.0 - 0.25 * np.exp(-(((r - 0.17) / 0.03) ** 2))  # worn edge around each hole
    return mix((0.02, 0.015, 0.01), (1.0, 1.0, 1.0), hole) * board * rim[..., None] + (1 - hole)[..., None] * 0.02


def books(h: int, w: int) -> np.ndarray:
    """A bookcase front: 4 shelves of upright book spines (random widths, heights and bindings,
    some with gilt bands), dark gaps behind them, a brown shelf board under each row."""
    rng = np.random.default_rng(27)
    y, x = _grid(h, w)
    rows = 4
    row, fv = np.floor(y * rows).astype(int), y * rows % 1.0
    bindings = np.array(
        [[0.35, 0.04, 0.04], [0.05, 0.08, 0.3], [0.06, 0.22, 0.08], [0.5, 0.36, 0.12], [0.05, 0.05, 0.05],
         [0.55, 0.45, 0.35], [0.25, 0.08, 0.2], [0.6, 0.15, 0.05]]
    )  # fmt: skip
    out = np.empty((h, w, 3))
    for r in range(rows):
        widths = rng.uniform(0.015, 0.045, 60)
        edges = np.cumsum(widths) - rng.uniform(0.0, 0.02)
        m = row == r
        k = np.searchsorted(edges, x[m])  # book index along the shelf
        top = 0.1 + 0.25 * rng.random(len(edges) + 1)  # book tops (fraction of the row from its top)
        colour = bindings[rng.integers(len(bindings), size=len(edges) + 1)] * rng.uniform(0.7, 1.2, (len(edges) + 1, 1))
        gilt = rng.random(len(edges) + 1) < 0.4
        left = np.concatenate([[0.0], edges])[k]
        across = (x[m] - left) / np.concatenate([widths, [0.03]])[k]  # 0 .. 1 across the spine
        v = fv[m]
        spine = colour[k] * (0.6 + 0.4 * np.sin(np.pi * np.clip(across, 0, 1)))[:, None]  # rounded spine
        band = gilt[k] & ((np.abs(v - top[k] - 0.12) < 0.015) | (np.abs(v - 0.78) < 0.015))
        spine = np.where(band[:, None], np.array([0.7, 0.55, 0.2]), spine)
        cell = np.where((v < top[k])[:, None], np.array([0.03, 0.02, 0.015]), spine)  # the dark case behind
        out[m] = np.where((v > 0.9)[:, None], np.array([0.3, 0.17, 0.08]) * (1.1 - v)[:, None] * 3, cell)
    return out * (0.85 + 0.15 * fbm(h, w, rng, cells=16))[..., None]


def carpet(h: int, w: int) -> np.ndarray:
    """A worn oriental runner: red field of repeating navy lozenges with cream centres, a navy and
    cream border along both long edges."""
    rng = np.random.default_rng(28)
    y, x = _grid(h, w)
    lozenge = np.abs((x * 4 % 1.0) - 0.5) + np.abs((y * 4 % 1.0) - 0.5)  # 0 at centres, 0.5 at edges
    field = np.where(
        (lozenge < 0.12)[..., None],
        np.array([0.75, 0.65, 0.45]),
        np.where((lozenge < 0.3)[..., None], np.array([0.05, 0.07, 0.22]), np.array([0.42, 0.05, 0.04])),
    )
    edge = np.minimum(x, 1 - x)
    border = np.where((edge < 0.06)[..., None], np.array([0.05, 0.07, 0.22]), np.array([0.72, 0.64, 0.46]))
    rug = np.where((edge < 0.1)[..., None], border, field)
    wear = 0.7 + 0.3 * fbm(h, w, rng, cells=12) + 0.08 * (rng.random((h, w)) - 0.5)  # pile and fading
    return rug * wear[..., None]


@dataclass(frozen=True)
class Pattern:
    shape: tuple[int, int]  # (h, w) texels
    make: Callable[[int, int], np.ndarray]


PATTERNS = {
    "marble": Pattern((256, 256), marble),
    "wood": Pattern((256, 256), wood),
    "weave": Pattern((256, 256), weave),
    "cobbles": Pattern((256, 256), cobbles),
    "masonry": Pattern((256, 384), masonry),
    "tiles": Pattern((256, 256), tiles),
    "foliage": Pattern((256, 256), foliage),
    "glazing": Pattern((256, 384), glazing),
    "pegboard": Pattern((256, 256), pegboard),
    "books": Pattern((256, 256), books),
    "carpet": Pattern((256, 256), carpet),
}


@functools.cache
def pattern(kind: str) -> np.ndarray:
    """Linear RGB (h, w, 3) float64 in [0, 1] of pattern ``kind`` (read-only, cached)."""
    if kind not in PATTERNS:
        raise ValueError(f"unknown procedural texture 'proc:{kind}'; available: {', '.join(PATTERNS)}")
    p = PATTERNS[kind]
    img = np.clip(p.make(*p.shape), 0.0, 1.0)
    img.setflags(write=False)
    return img
