"""LLFF folders: read real captures, write the canonical scene layout every later rule reads.

An LLFF folder holds ``images/`` (full size) and optionally ``images_4/``, ``images_8/`` (downscaled
by that factor) plus ``poses_bounds.npy`` (N x 17; see :mod:`spc3d.cameras`). ``hwf`` in the file
refers to the full-size images, so the focal length is rescaled to the folder actually loaded.

The canonical scene folder written by :func:`write_scene` (``results/scenes/{scene}/``) is an LLFF
folder at the working resolution, whose ``hwf`` already matches its ``images/``:

    images/{name}.png     sRGB, 8 bit
    depth/{name}.exr      ground-truth depth along the camera z axis (built-in scenes only)
    poses_bounds.npy      N x 17, LLFF convention
    intrinsics.npy        N x 4 fx, fy, cx, cy in pixels of the ``hwf`` size; only when LLFF's one
                          focal and centred principal point cannot hold them (e.g. COLMAP scenes)
    scene.json            provenance: source, resolution, seed, settings, wall time

``intrinsics.npy`` may sit in any LLFF folder: like ``hwf`` it refers to the size written in
``poses_bounds.npy`` and is rescaled to the images loaded. Folders without it read as plain LLFF.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from spc3d import io
from spc3d.cameras import Cameras, cameras_to_llff, llff_to_cameras

INTRINSICS_FILE = "intrinsics.npy"  # optional, beside poses_bounds.npy (see the module docstring)


class NoReference(ValueError):
    """The scene has no reference RGB views (a SPAD capture without ``images/``)."""


def has_reference(scene_dir: str | os.PathLike) -> bool:
    """Whether a canonical scene folder holds reference RGB views (every scene but a capture without them)."""
    meta = Path(scene_dir) / "scene.json"
    return not meta.exists() or io.read_json(meta).get("reference", True) is not False


@dataclass
class SceneData:
    """Views of one scene. images: (N, H, W, 3) float32 sRGB in [0, 1] (None when read without them:
    see :func:`read_scene`); names: file stems."""

    images: np.ndarray | None
    cameras: Cameras
    names: list[str]
    depths: np.ndarray | None = None  # (N, H, W) float32, when known
    meta: dict = field(default_factory=dict)


def image_folder(root: str | os.PathLike, factor: int) -> Path:
    """``images/`` for factor 1, else ``images_{factor}/``; a clear error lists what exists."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"scene folder {root} does not exist (expected an LLFF folder)")
    folder = root / ("images" if factor == 1 else f"images_{factor}")
    if not folder.is_dir():
        found = sorted(p.name for p in root.glob("images*") if p.is_dir())
        raise FileNotFoundError(
            f"{folder} does not exist; choose an LLFF factor whose folder is present (found: {found or 'none'})"
        )
    return folder


def load_llff(root: str | os.PathLike, factor: int = 8, width: int | None = None) -> SceneData:
    """Load an LLFF folder at ``factor``, then area-downscale to ``width`` (aspect kept) if given."""
    files, poses_bounds = llff_contents(root, factor)
    images = read_views(files)
    cams = llff_cameras(root, poses_bounds, images.shape[1], images.shape[2])
    scene = SceneData(images, cams, [f.stem for f in files], meta={"source": str(root), "factor": factor})
    return resize_scene(scene, width) if width else scene


def llff_contents(root: str | os.PathLike, factor: int) -> tuple[list[Path], np.ndarray]:
    """The image files at ``factor`` and the checked ``poses_bounds`` of an LLFF folder.

    Cheap (no image is decoded), so the workflow calls it at parse time too: a folder whose poses
    are not finite, whose bounds are not 0 < near < far, whose image count differs from its
    pose count, or whose ``intrinsics.npy`` (optional) is malformed is refused before any job runs.
    """
    root = Path(root)
    folder = image_folder(root, factor)
    pb_path = root / "poses_bounds.npy"
    if not pb_path.is_file():
        raise FileNotFoundError(f"{pb_path} is missing (an LLFF folder needs poses_bounds.npy, N x 17)")
    try:
        poses_bounds = io.load_npy(pb_path)
    except (OSError, ValueError) as e:
        raise ValueError(f"cannot read {pb_path}: {e} (expected a .npy array, N x 17)") from None
    check_poses_bounds(poses_bounds, pb_path)
    files = io.list_images(folder)
    if len(files) != len(poses_bounds):
        raise ValueError(
            f"{folder} holds {len(files)} images but {pb_path} has {len(poses_bounds)} poses; they must match"
        )
    check_image_headers(files)
    read_intrinsics(root, poses_bounds)
    return files, poses_bounds


MIN_TRAIN_VIEWS = 2  # a 3D fit needs parallax between at least two training views
SAME_CENTRE = 1e-4  # camera centres closer than this fraction of the median near bound are one position


def check_views(poses_bounds: np.ndarray, files: list[Path], path) -> None:
    """What a real scene's views must give a 3D fit, checked when the workflow parses a configured
    LLFF folder (:func:`spc3d.jobs.llff_input_files`; a canonical folder of any views reads fine):
    the ``hwf`` size of the poses in the images' aspect (not swapped), at least
    :data:`MIN_TRAIN_VIEWS` training views beside the held-out ones (every 8th), and camera centres
    that are not all one point (no parallax, nothing to triangulate)."""
    from spc3d.cameras import split_views

    h, w, _ = io.image_shape(files[0])
    ph, pw = float(poses_bounds[0, 4]), float(poses_bounds[0, 9])  # hwf: column 5 of the 3x5 pose
    if abs(w / h - ph / pw) < 0.02 * (w / h) and abs(w / h - pw / ph) > 0.02 * (w / h):
        raise ValueError(
            f"{path}: the poses' hwf says {ph:g} high x {pw:g} wide but the images are {w}x{h} (WxH): height "
            "and width look swapped in column 5 of the poses (h, w, f)"
        )
    train, _ = split_views(len(poses_bounds))
    if len(train) < MIN_TRAIN_VIEWS:
        raise ValueError(
            f"{path}: {len(poses_bounds)} view(s) leave {len(train)} training view(s) beside the held-out "
            f"ones (every 8th); a 3D fit needs at least {MIN_TRAIN_VIEWS}"
        )
    centres = poses_bounds[:, :15].reshape(-1, 3, 5)[:, :, 3]
    spread, near = np.linalg.norm(centres - centres.mean(0), axis=1).max(), float(np.median(poses_bounds[:, 15]))
    if spread <= SAME_CENTRE * near:
        raise ValueError(
            f"{path}: all {len(poses_bounds)} cameras sit at one position (centres within {spread:.3g} of their "
            f"mean against a near bound of {near:.3g}): no parallax to reconstruct from"
        )


def read_intrinsics(root: str | os.PathLike, poses_bounds: np.ndarray) -> np.ndarray | None:
    """The checked ``intrinsics.npy`` of an LLFF folder (N x 4 fx, fy, cx, cy, for the ``hwf``
    size of ``poses_bounds``), or None when the folder has none."""
    path = Path(root) / INTRINSICS_FILE
    if not path.is_file():
        return None
    try:
        intr = io.load_npy(path)
    except (OSError, ValueError) as e:
        raise ValueError(f"cannot read {path}: {e} (expected a .npy array, N x 4 fx, fy, cx, cy)") from None
    if intr.shape != (len(poses_bounds), 4) or not np.issubdtype(intr.dtype, np.number):
        raise ValueError(
            f"{path}: array of shape {intr.shape} ({intr.dtype}); expected {len(poses_bounds)} x 4 "
            f"numbers (fx, fy, cx, cy per view of poses_bounds.npy)"
        )
    bad = np.flatnonzero(~np.isfinite(intr).all(axis=1) | (intr[:, :2] <= 0).any(axis=1))
    if bad.size:
        raise ValueError(f"{path}: view(s) {_first(bad)} have non-finite intrinsics or a focal length <= 0")
    return intr.astype(np.float64)


def llff_cameras(root: str | os.PathLike, poses_bounds: np.ndarray, height: int, width: int) -> Cameras:
    """Cameras of an LLFF folder for images of (height, width): ``poses_bounds``, with the
    folder's ``intrinsics.npy`` (rescaled from the ``hwf`` size like the focal) replacing the
    ``hwf`` focal and centred principal point when present."""
    cams = llff_to_cameras(poses_bounds, height, width)
    intr = read_intrinsics(root, poses_bounds)
    if intr is None:
        return cams
    h0, w0 = poses_bounds[:, 4], poses_bounds[:, 9]  # per view: h, w of the pose's 5th column (hwf)
    sx, sy = width / w0, height / h0
    return replace(cams, intrinsics=intr * np.stack([sx, sy, sx, sy], axis=1))


def needs_intrinsics_file(cams: Cameras) -> bool:
    """Whether LLFF's one focal per view and centred principal point would lose part of
    ``cams.intrinsics`` (beyond round-off: 1e-9 relative)."""
    fx, fy, cx, cy = cams.intrinsics.T
    tol = 1e-9 * max(cams.width, cams.height)
    return bool(
        (np.abs(fy - fx) > 1e-9 * np.abs(fx)).any()
        or (np.abs(cx - cams.width / 2) > tol).any()
        or (np.abs(cy - cams.height / 2) > tol).any()
    )


def view_axes(poses_bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centres, viewing directions, right axes) of LLFF poses, each (N, 3): the rotation's columns
    are [down, right, back], so a camera looks along -back."""
    poses = poses_bounds[:, :15].reshape(-1, 3, 5)
    return poses[:, :, 3], -poses[:, :, 2], poses[:, :, 1]


def focus_depths(poses_bounds: np.ndarray) -> np.ndarray | None:
    """Depth along each camera's viewing direction of the point its optical axes pass closest to
    (least squares; LLFF's own ``focus`` point), or None when the axes are (nearly) parallel and
    meet nowhere in particular. A forward-facing rig looks towards it: positive depths, of the
    order of its near / far bounds."""
    centres, dirs, _ = view_axes(poses_bounds)
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    proj = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]  # onto the plane normal to each axis
    a, b = proj.sum(0), (proj @ centres[:, :, None]).sum(0)[:, 0]
    eig = np.linalg.eigvalsh(a)
    if eig[0] < 1e-6 * eig[-1] * len(dirs):
        return None
    point = np.linalg.solve(a, b)
    return ((point - centres) * dirs).sum(1)


SCALE_MISMATCH = 50.0  # camera spread or focus depth this many times the far bound (or 1/this of near)
ORDER_PAIRS = 8  # consecutive view pairs with a sideways camera motion needed to judge the images' motion


def rig_warnings(poses_bounds: np.ndarray, files: list[Path] | None = None) -> list[str]:
    """What may be wrong with an LLFF folder's poses but cannot be refused for sure (a warning each;
    the scene's records carry them into the tables' captions): translations in another unit than
    the bounds (mm against m; from the poses alone, so the workflow checks it at parse time too),
    and, from thumbnails of the images (``files``: :func:`motion_agreement`, about 50 ms an image,
    so only the prepare_scene job reads them), poses in OpenCV axes instead of LLFF's
    [down, right, back] (the images move with the LLFF "down" axis, not its "right" one) or pose
    rows in the reverse order of the images (they move the wrong way)."""
    out = []
    centres, _, _ = view_axes(poses_bounds)
    near, far = float(np.median(poses_bounds[:, 15])), float(np.median(poses_bounds[:, 16]))
    spread = float(np.linalg.norm(centres - centres.mean(0), axis=1).max())
    depths = focus_depths(poses_bounds)
    depth = float(np.median(depths)) if depths is not None and (depths > 0).all() else None
    if spread > SCALE_MISMATCH * far or (depth is not None and depth > SCALE_MISMATCH * far):
        aim = f" and aim at depth {depth:.3g}" if depth is not None else ""
        out.append(
            f"camera positions spread over {spread:.3g}{aim} against bounds {near:.3g}..{far:.3g}: the "
            "translations look like another unit than the bounds (mm against m?); scale one of them"
        )
    elif depth is not None and depth * SCALE_MISMATCH < near:
        out.append(
            f"cameras aim at depth {depth:.3g} against bounds {near:.3g}..{far:.3g}: the bounds look like another "
            "unit than the translations (mm against m?); scale one of them"
        )
    if files is None or len(files) != len(poses_bounds):
        return out
    thumbs = [_thumbnail(io.read_rgb(f)) for f in files]
    right, n_right = motion_agreement(poses_bounds, thumbs, 1)
    down, n_down = motion_agreement(poses_bounds, thumbs, 0)
    if n_down >= ORDER_PAIRS and down >= 0.85 and right < 0.6:
        out.append(
            f"the images move sideways with the poses' first axis ({down:.0%} of {n_down} view pairs), which LLFF "
            "reads as 'down', not with its second ('right'): the poses look like OpenCV axes [right, down, "
            "forward]; LLFF's 3x3 columns are [down, right, back] (convert as [c1, c0, -c2])"
        )
    elif n_right >= ORDER_PAIRS and right < 0.1:
        out.append(
            f"consecutive images move the wrong way for their poses in {1 - right:.0%} of {n_right} view pairs: "
            "the pose rows look reversed against the images (sorted by file name), or the images mirrored"
        )
    return out


def motion_agreement(poses_bounds: np.ndarray, thumbs: list[np.ndarray], axis: int) -> tuple[float, int]:
    """(share, count) of the consecutive views whose camera moves along its pose column ``axis``
    (1: LLFF's right) whose image content moves the opposite way horizontally, as it must for the
    right axis (a camera moving right sees the scene move left); from phase correlation of grey
    thumbnails. Pairs with little motion along the axis (below half the median) do not vote."""
    poses = poses_bounds[:, :15].reshape(-1, 3, 5)
    centres, axes = poses[:, :, 3], poses[:, :, axis]
    steps = np.array([float((centres[i + 1] - centres[i]) @ axes[i]) for i in range(len(thumbs) - 1)])
    scale = float(np.median(np.abs(steps))) if steps.size else 0.0
    votes = []
    for i, step in enumerate(steps):
        if scale > 0 and abs(step) >= 0.5 * scale and (shift := _shift_x(thumbs[i], thumbs[i + 1])):
            votes.append(np.sign(shift) == -np.sign(step))
    return (float(np.mean(votes)) if votes else 0.0), len(votes)


def _thumbnail(image: np.ndarray, width: int = 64) -> np.ndarray:
    grey = np.asarray(image, np.float64).mean(axis=2) if image.ndim == 3 else np.asarray(image, np.float64)
    f = max(1, grey.shape[1] // width)
    h, w = grey.shape[0] // f * f, grey.shape[1] // f * f
    return grey[:h, :w].reshape(h // f, f, w // f, f).mean(axis=(1, 3))


def _shift_x(a: np.ndarray, b: np.ndarray) -> int:
    """Horizontal shift (px) of ``b``'s content against ``a``'s (positive: to the right)."""
    window = np.hanning(a.shape[0])[:, None] * np.hanning(a.shape[1])[None, :]
    fa, fb = np.fft.rfft2((a - a.mean()) * window), np.fft.rfft2((b - b.mean()) * window)
    cross = fa.conj() * fb
    corr = np.fft.irfft2(cross / (np.abs(cross) + 1e-12), s=a.shape)
    x = int(np.unravel_index(np.argmax(corr), corr.shape)[1])
    return x - a.shape[1] if x > a.shape[1] // 2 else x


def check_poses_bounds(pb: np.ndarray, path) -> None:
    """LLFF poses_bounds (N, 17): finite numbers, proper rotations, positive hwf, 0 < near < far."""
    if pb.ndim != 2 or pb.shape[1] != 17 or pb.shape[0] == 0 or not np.issubdtype(pb.dtype, np.number):
        raise ValueError(
            f"{path}: array of shape {pb.shape} ({pb.dtype}); LLFF poses_bounds.npy is N x 17 numbers "
            f"(a 3x5 pose [R | t | h w f] per view, then near and far)"
        )
    bad = np.flatnonzero(~np.isfinite(pb).all(axis=1))
    if bad.size:
        raise ValueError(
            f"{path}: non-finite poses (NaN or inf) in view(s) {_first(bad)}; every pose, hwf and "
            f"bound must be a finite number"
        )
    poses = pb[:, :15].reshape(-1, 3, 5)
    rot = poses[:, :, :3]
    err = np.abs(rot @ rot.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((err > 1e-3) | (np.linalg.det(rot) <= 0))
    if bad.size:
        raise ValueError(f"{path}: the 3x3 part of view(s) {_first(bad)} is not a rotation (orthonormal, det +1)")
    bad = np.flatnonzero((poses[:, :, 4] <= 0).any(axis=1))
    if bad.size:
        raise ValueError(
            f"{path}: view(s) {_first(bad)} have height, width or focal length <= 0 (column 5 of "
            f"the pose is h, w, f in pixels)"
        )
    near, far = pb[:, 15], pb[:, 16]
    bad = np.flatnonzero((near <= 0) | (far <= near))
    if bad.size:
        i = bad[0]
        raise ValueError(
            f"{path}: view(s) {_first(bad)} have bounds near={near[i]:g}, far={far[i]:g}; need "
            f"0 < near < far (scene depths in front of the camera)"
        )


def _first(indices: np.ndarray, n: int = 5) -> str:
    shown = ", ".join(map(str, indices[:n]))
    return shown + (f" (and {len(indices) - n} more)" if len(indices) > n else "")


def check_image_headers(files: list[Path]) -> None:
    """Every view RGB (3 channels, or 4 with alpha) and of one size, judged from the file headers."""
    first = None
    for f in files:
        h, w, c = io.image_shape(f)
        if c not in (3, 4):
            raise ValueError(
                f"{f}: {c} channel(s); the views of a scene must be RGB (3 channels, or 4 with "
                f"alpha): convert it, or remove it together with its row of poses_bounds.npy"
            )
        first = first or (f, h, w)
        if (h, w) != first[1:]:
            raise ValueError(
                f"{f} is {w}x{h} pixels but {first[0].name} is {first[2]}x{first[1]}: every image of "
                f"{f.parent} must have the same size"
            )


def read_views(files: list[Path]) -> np.ndarray:
    """(N, H, W, 3) sRGB in [0, 1] of a scene's views (alpha dropped; see :func:`check_image_headers`)."""
    return np.stack([np.clip(io.read_image(f)[:, :, :3], 0.0, 1.0) for f in files])


def resize_scene(scene: SceneData, width: int, height: int | None = None) -> SceneData:
    """Area-resample every view to ``width`` (height keeps the aspect unless given)."""
    n, h0, w0, _ = scene.images.shape
    height = height or max(1, int(round(width * h0 / w0)))
    if (height, width) == (h0, w0):
        return scene
    Ay, Ax = area_matrix(h0, height), area_matrix(w0, width)
    images = np.einsum("yh,nhwc,xw->nyxc", Ay, scene.images, Ax, optimize=True).astype(np.float32)
    depths = None if scene.depths is None else nearest_resize_depth(scene.depths, height, width)
    return SceneData(images, scene.cameras.rescaled(height, width), scene.names, depths, dict(scene.meta))


def nearest_resize_depth(depths: np.ndarray, height: int, width: int) -> np.ndarray:
    """Depth (N, H, W) sampled at each output pixel's centre: averaging across an occlusion edge
    would invent depths that belong to no surface, so depth is resampled, never filtered."""
    _, h0, w0 = depths.shape
    rows = np.minimum(((np.arange(height) + 0.5) * h0 / height).astype(int), h0 - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * w0 / width).astype(int), w0 - 1)
    return depths[:, rows][:, :, cols].astype(np.float32)


def area_matrix(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) weights averaging the exact overlap of each output pixel with input pixels.

    The area filter of image resizing (OpenCV's INTER_AREA for shrinking), valid for any ratio.
    """
    edges = np.linspace(0.0, n_in, n_out + 1)
    lo, hi = edges[:-1, None], edges[1:, None]
    px = np.arange(n_in)[None, :]
    overlap = np.clip(np.minimum(hi, px + 1) - np.maximum(lo, px), 0.0, None)
    return overlap / overlap.sum(1, keepdims=True)


def write_scene(out_dir: str | os.PathLike, scene: SceneData, record: dict) -> None:
    """Write the canonical scene folder atomically (built as a temporary folder, then renamed).

    ``intrinsics.npy`` is written only when ``poses_bounds.npy`` cannot hold the intrinsics
    (see :func:`needs_intrinsics_file`). A scene without reference views (``images`` None: a SPAD
    capture without RGB) has no ``images/``; ``scene.json`` then lists its view names and says
    ``"reference": false``, and only :func:`read_scene` ``with_images=False`` reads it."""
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        for i, name in enumerate(scene.names):
            if scene.images is not None:
                io.write_image(tmp / "images" / f"{name}.png", scene.images[i])
            if scene.depths is not None:
                io.write_image(tmp / "depth" / f"{name}.exr", scene.depths[i][:, :, None])
        io.save_npy(tmp / "poses_bounds.npy", cameras_to_llff(scene.cameras))
        if needs_intrinsics_file(scene.cameras):
            io.save_npy(tmp / INTRINSICS_FILE, scene.cameras.intrinsics)
        io.write_json(
            tmp / "scene.json",
            {
                **scene.meta,
                **record,
                "reference": scene.images is not None,
                **({} if scene.images is not None else {"names": list(scene.names)}),
                "views": len(scene.names),
                "height": scene.cameras.height,
                "width": scene.cameras.width,
            },
        )


def read_scene(scene_dir: str | os.PathLike, with_depth: bool = False, with_images: bool = True) -> SceneData:
    """Read a canonical scene folder written by :func:`write_scene`.

    ``with_images=False`` reads the cameras and view names only (``images`` is None): what every
    consumer that must not see the ground truth (non-oracle sources, renderers) asks for.
    """
    scene_dir = Path(scene_dir)
    meta_path = scene_dir / "scene.json"
    meta = io.read_json(meta_path) if meta_path.exists() else {}
    if meta.get("reference") is False:
        if with_images:
            raise NoReference(
                f"{scene_dir} has no reference views (a capture without images/): its rows get outputs and "
                "no-reference statistics only; a source or metric that needs the ground truth cannot run on it"
            )
        pb = io.load_npy(scene_dir / "poses_bounds.npy")
        data = SceneData(None, llff_cameras(scene_dir, pb, meta["height"], meta["width"]), list(meta["names"]))
    elif with_images:
        data = load_llff(scene_dir, factor=1)
    else:
        files, poses_bounds = llff_contents(scene_dir, 1)
        h, w, _ = io.image_shape(files[0])
        data = SceneData(None, llff_cameras(scene_dir, poses_bounds, h, w), [f.stem for f in files])
    data.meta = meta
    if with_depth and (scene_dir / "depth").is_dir():
        data.depths = np.stack([io.read_image(scene_dir / "depth" / f"{n}.exr")[:, :, 0] for n in data.names])
    return data
