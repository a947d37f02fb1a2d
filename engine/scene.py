"""Scenes: a COLMAP workspace turned into views with cameras, depth ranges and source views.

``survey_scene`` reads ``SCENE/sparse`` (or ``sparse/0``) through pycolmap and checks everything that needs no
pixels (model, image names, each image's header and size against its camera, points); for distorted camera models it
computes the undistorted pinhole camera from the camera alone. It rescales every camera to the working resolution
(``max_image_size``) with exact intrinsics, and computes per view (Schönberger et al. 2016):

- the depth range from the sparse points the view observes: the 1st / 99th percentile of their
  depths, stretched by (0.75, 1.25) as COLMAP does, then relaxed by (0.6, 1.2) as ACMM does;
- the source views: the views sharing most sparse points with it among those whose 75th-percentile
  triangulation angle is at least 1° (COLMAP's ``__auto__`` selection).

``load_scene`` builds on the survey: it undistorts distorted workspaces at the working size into a cache
(``engine.io.undistort``, in a child process) and checks the optional ground truth. ``deepc info`` prints the survey.

Images and ground-truth depth are read lazily, at the working resolution; a cache holds an 8-bit image already at
the working size as its file's bytes (3 B/px, converted to float32 on access, the same floats), others as float32.
A per-view task holds a :class:`SceneViews` (``Scene.subset``): its view and source views and their images, not the
scene's sparse model (``engine.run.distributed``).
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
import warnings
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

import numpy as np

from engine.core.camera import Camera, rescaled_size
from engine.core.errors import DeepCError
from engine.core.options import Options, option
from engine.core.resample import resample_depth
from engine.core.words import plural
from engine.io.colmap_model import PINHOLE_MODELS, SparseCamera, SparseModel, find_model_dir, read_sparse_model
from engine.io.dense import read_dense_map_header, read_depth_map
from engine.io.images import decode_image, image_size, image_to_float, resize_area, to_gray
from engine.io.undistort import LOG_FILE, cache_key, cached_workspace, undistort_workspace, undistorted_camera

# The default working size (``default_image_size``), after OpenMVS's DensifyPointCloud (--resolution-level 1
# --max-resolution 2560 --min-resolution 640): half the longest side, within these bounds, never above it.
WORKING_SIZE_DIVISOR = 2
WORKING_SIZE_MAX = 2560
WORKING_SIZE_MIN = 640
# Fewer observed points than this and a view's depth range falls back to all points it sees.
_MIN_POINTS_FOR_RANGE = 5
SCENE_IMAGE_CACHE = 64  # views whose image a Scene keeps
TASK_IMAGE_CACHE = 16  # views whose image a process running per-view tasks keeps (all its SceneViews together)


@dataclasses.dataclass
class SceneOptions(Options):
    """How a COLMAP workspace becomes views: working size, depth ranges, source views."""

    max_image_size: int | None = option(None, "longest image side; unset: half, within 640..2560; 0: full size",
                                        unit="px", source="OpenMVS", low=0, metavar="PX", absent=0)
    num_source_views: int = option(10, "source views per reference view (COLMAP, ACMM: 20)", source="ours", low=1,
                                   high=32, metavar="N")
    min_triangulation_angle: float = option(1.0, "a source view needs this 75th-percentile triangulation angle",
                                            unit="degrees", source="COLMAP", low=0, below=90, metavar="DEGREES")
    depth_percentiles: tuple[float, float] = option((0.01, 0.99), "percentiles of sparse-point depths",
                                                    source="COLMAP", low=0, high=1, ordered="<", cli=False)
    depth_stretch: tuple[float, float] = option((0.75, 1.25), "factors applied to the percentile depths",
                                                source="COLMAP", above=0, cli=False)
    depth_relax: tuple[float, float] = option((0.6, 1.2), "further factors on the range", source="ACMM", above=0,
                                              cli=False)
    depth_range: tuple[float, float] | None = option(None, "this depth range for every view instead of the sparse "
                                                     "points'", unit="model units", source="ours", above=0,
                                                     ordered="<", metavar="MIN,MAX")
    undistort: bool = option(True, "undistort non-pinhole cameras with pycolmap into a cache (else refuse them)",
                             source="ours")
    cache_dir: str = option("", "folder for undistorted copies (default: ~/.cache/deepc)", source="ours", cli=False)


@dataclasses.dataclass(eq=False)
class View:
    """One reference view at the working resolution.

    Attributes:
        index: position in ``Scene.views``.
        name: image name exactly as in the COLMAP model (may contain '/').
        image_id: COLMAP image id.
        camera: camera at the working resolution (``camera.width`` × ``camera.height``).
        original_size: (width, height) of the image file.
        depth_range: (min, max) camera-frame depth for PatchMatch sampling and validity checks.
        source_views: indices of the source views, best first.
        num_points: sparse points observed by this view.
    """

    index: int
    name: str
    image_id: int
    camera: Camera
    original_size: tuple[int, int]
    depth_range: tuple[float, float]
    source_views: list[int]
    num_points: int


class Scene:
    """A loaded scene: views plus lazy access to images and ground truth at the working resolution."""

    def __init__(self, root: Path, image_root: Path, model: SparseModel, views: list[View],
                 options: SceneOptions, shared_points: np.ndarray, gt_depth_paths: list[Path | None],
                 gt_points_path: Path | None, image_sizes: list[tuple[int, int]] | None = None):
        self.root = root
        self.name = root.resolve().name
        self.image_root = image_root
        self.model = model
        self.views = views
        self.options = options
        self.shared_points = shared_points  # (n, n) sparse points seen by both views
        self.gt_depth_paths = gt_depth_paths
        self.gt_points_path = gt_points_path
        # (width, height) of each view's image file before undistortion (None: the views' ``original_size``)
        self.image_sizes = image_sizes
        self._image = lru_cache(maxsize=SCENE_IMAGE_CACHE)(self._load_image)

    def __len__(self) -> int:
        return len(self.views)

    @property
    def has_gt_depth(self) -> bool:
        return any(p is not None for p in self.gt_depth_paths)

    @property
    def has_gt_points(self) -> bool:
        return self.gt_points_path is not None

    def image_path(self, i: int) -> Path:
        return self.image_root / self.views[i].name

    def _load_image(self, i: int) -> np.ndarray:
        view = self.views[i]
        return _view_pixels(self.image_path(i), view.original_size, view.camera.size)

    def image(self, i: int) -> np.ndarray:
        """(H, W, 3) float32 RGB in [0, 1] at the working resolution (read-only, cached)."""
        return _as_image(self._image(i))

    def forget_images(self) -> None:
        """Empty the image cache (12 B a pixel of every view decoded at another size): a run's later stages read
        an image again from its file if they need it."""
        self._image.cache_clear()

    def subset(self, indices: list[int]) -> SceneViews:
        """The views ``indices`` alone, with their images: what a per-view task needs (a few kB pickled)."""
        return SceneViews(self.image_root, {j: self.views[j] for j in indices})

    def gray(self, i: int) -> np.ndarray:
        """(H, W) float32 grey image in [0, 1] at the working resolution."""
        return to_gray(self.image(i))

    def gt_depth(self, i: int) -> np.ndarray | None:
        """(H, W) float32 ground-truth depth at the working resolution (0 = unknown), or None."""
        path = self.gt_depth_paths[i]
        if path is None:
            return None
        return resample_depth(read_depth_map(path), self.views[i].camera.size)

    def gt_views(self) -> list[tuple[Camera, np.ndarray]]:
        """(camera, GT depth) at the working resolution for every view with GT depth (for the
        unobserved-space rule of the evaluation, Schöps et al. 2017)."""
        return [(v.camera, self.gt_depth(v.index)) for v in self.views if self.gt_depth_paths[v.index] is not None]

    def overlapping_views(self, i: int, max_views: int = 50) -> list[int]:
        """Views sharing most sparse points with view ``i`` (no angle gate; fusion's ``check_num_images``)."""
        shared = self.shared_points[i].copy()
        shared[i] = 0
        order = np.argsort(-shared, kind="stable")
        return [int(j) for j in order[:max_views] if shared[j] > 0]

    def summary(self) -> str:
        """A human-readable table of the views."""
        lines = [f"scene {self.name}: {plural(len(self.views), 'view')}, "
                 f"{plural(len(self.model.points), 'sparse point')}, "
                 f"GT depth: {'yes' if self.has_gt_depth else 'no'}, GT points: "
                 f"{'yes' if self.has_gt_points else 'no'}"]
        return "\n".join(lines + views_table(self.views))


def views_table(views: list[View]) -> list[str]:
    """Lines of a table of ``views``: name, working size, sparse points, depth range, source views."""
    lines = [f"{'view':<28} {'size':>10} {'points':>7} {'depth range':>21}  source views"]
    for v in views:
        size = f"{v.camera.width}x{v.camera.height}"
        rng = f"{v.depth_range[0]:.4g} .. {v.depth_range[1]:.4g}"
        lines.append(f"{v.name[:28]:<28} {size:>10} {v.num_points:>7} {rng:>21}  "
                     f"{' '.join(str(j) for j in v.source_views) or '(none)'}")
    return lines


class SceneViews:
    """Some views of a scene, by their index in ``Scene.views``, with their images at the working resolution: what a
    per-view task holds (its view and its source views), instead of the whole scene and its sparse model.

    ``views`` is a dict (index -> :class:`View`), so ``views[j]``, :meth:`image` and :meth:`gray` read as a
    :class:`Scene`'s. The images go through one cache per process (``TASK_IMAGE_CACHE`` views, keyed by file and
    size), so a worker's memory is bounded whatever the number of views of the scene.
    """

    def __init__(self, image_root: Path, views: dict[int, View]):
        self.image_root, self.views = Path(image_root), views

    def image(self, i: int) -> np.ndarray:
        """(H, W, 3) float32 RGB in [0, 1] at the working resolution (read-only), as ``Scene.image``."""
        view = self.views[i]
        path = self.image_root / view.name
        try:
            stat = path.stat()
            changed = (stat.st_mtime_ns, stat.st_size)
        except OSError:
            changed = None  # decode_image says what is wrong
        return _as_image(_task_pixels(str(path), changed, view.original_size, view.camera.size))

    def gray(self, i: int) -> np.ndarray:
        """(H, W) float32 grey image in [0, 1] at the working resolution."""
        return to_gray(self.image(i))


def _view_pixels(path: Path, original_size: tuple[int, int], size: tuple[int, int]) -> np.ndarray:
    """A view's image as a cache holds it (read-only): the file's uint8 pixels when they are 8-bit RGB already at the
    working ``size`` (:func:`_as_image` turns them into the floats ``read_image`` gives), else the (H, W, 3) float32
    image area-resized to ``size``."""
    pixels = decode_image(path)
    if (pixels.shape[1], pixels.shape[0]) != tuple(original_size):
        raise DeepCError(f"image is {pixels.shape[1]}x{pixels.shape[0]}, its header said "
                         f"{original_size[0]}x{original_size[1]}", path)
    if pixels.dtype != np.uint8 or tuple(size) != tuple(original_size):
        pixels = resize_area(image_to_float(pixels), size)
    pixels.setflags(write=False)
    return pixels


@lru_cache(maxsize=TASK_IMAGE_CACHE)
def _task_pixels(path: str, changed: tuple[int, int] | None, original_size: tuple[int, int],
                 size: tuple[int, int]) -> np.ndarray:
    """:func:`_view_pixels`, cached by file, modification time and size (a worker outlives runs)."""
    return _view_pixels(Path(path), original_size, size)


def _as_image(pixels: np.ndarray) -> np.ndarray:
    """A cached image (see :func:`_view_pixels`) as (H, W, 3) float32 RGB in [0, 1], read-only."""
    if pixels.dtype != np.uint8:
        return pixels
    image = image_to_float(pixels)
    image.setflags(write=False)
    return image


@dataclasses.dataclass(eq=False)
class SceneSurvey:
    """A workspace as known without decoding a pixel or undistorting an image: the checked sparse model, the pinhole
    camera of each COLMAP camera (its undistorted camera for distorted models, computed from the camera alone), and
    the views at the working size with their depth ranges and source views. ``load_scene`` builds its
    :class:`Scene` from it; ``deepc info`` prints it.

    Attributes:
        model: the sparse model as read (distorted cameras included).
        cameras: camera_id -> the pinhole camera the views use before rescaling (``model.cameras`` for pinhole
            models, pycolmap's undistorted camera for the others).
        distorted: the camera models that need undistortion (empty for a pinhole workspace).
        image_sizes: (width, height) of each registered image's file, from its header, in ``model.images`` order.
    """

    root: Path
    model_dir: Path
    model: SparseModel
    cameras: dict[int, SparseCamera]
    views: list[View]
    shared_points: np.ndarray
    distorted: list[str]
    image_sizes: list[tuple[int, int]]
    options: SceneOptions
    gt_depth_paths: list[Path | None]
    gt_points_path: Path | None

    @property
    def name(self) -> str:
        return self.root.resolve().name

    @property
    def cache_root(self) -> Path:
        """Where undistorted copies of distorted workspaces are cached."""
        base = self.options.cache_dir or os.environ.get("DEEPC_CACHE", Path.home() / ".cache" / "deepc")
        return Path(base) / "undistorted"

    def cache_key(self) -> str:
        """The name of this workspace's undistorted copy in :attr:`cache_root`."""
        return cache_key(self.root, self.model_dir, [im.name for im in self.model.images],
                         self.options.max_image_size)

    def undistorted_size(self) -> int:
        """Longest side of the undistorted images, in pixels (0 for a pinhole workspace)."""
        return max((max(self.cameras[im.camera_id].width, self.cameras[im.camera_id].height)
                    for im in self.model.images), default=0) if self.distorted else 0


def default_image_size(longest: int) -> int:
    """The ``max_image_size`` the default gives images whose longest side is ``longest`` px: half of it, at most
    ``WORKING_SIZE_MAX`` and at least ``WORKING_SIZE_MIN``; 0 (full size) where that is not below ``longest``."""
    size = min(WORKING_SIZE_MAX, max(WORKING_SIZE_MIN, round(longest / WORKING_SIZE_DIVISOR)))
    return size if size < longest else 0


def resolved_image_size(options: SceneOptions, sizes: list[tuple[int, int]]) -> int:
    """The ``max_image_size`` a run of images of ``sizes`` (width, height) works at: the option when it is given (0
    keeps full size), else :func:`default_image_size` of the longest side (a run saves this value, so it re-runs
    as it ran whatever the default becomes)."""
    if options.max_image_size is not None:
        return options.max_image_size
    return default_image_size(max((max(size) for size in sizes), default=0))


def working_size_line(views: list[View], requested: int | None,
                      image_sizes: list[tuple[int, int]] | None = None) -> str:
    """'working size 1251×703 → 640×360 px (...)': the largest image's size and its view's working size, how that was
    chosen (``requested``: the ``max_image_size`` asked for, None for the default) and the flag that changes it.
    ``image_sizes``: the image files' sizes, where they differ from the views' ``original_size`` (distorted
    workspaces, undistorted at the working size); by default the latter."""
    full = image_sizes or [v.original_size for v in views]
    view = max(views, key=lambda v: (max(full[v.index]), v.index))
    (w, h), (ww, wh) = full[view.index], view.camera.size
    largest = "largest image " if len(set(full)) > 1 else ""
    size = f"{w}×{h} px, full size" if (w, h) == (ww, wh) else f"{w}×{h} → {ww}×{wh} px"
    if requested is None:
        how = (f"default: half the size, within {WORKING_SIZE_MIN}..{WORKING_SIZE_MAX} px, never above full size; "
               "--max-image-size N to change, 0 for full size")
    elif requested == 0:
        how = "--max-image-size 0"
    else:
        how = f"--max-image-size {requested}; 0 for full size"
    return f"working size: {largest}{size} ({how})"


def survey_scene(path: str | Path, options: SceneOptions | None = None) -> SceneSurvey:
    """Check a COLMAP workspace and compute its views without decoding or undistorting an image (seconds).

    The survey's options have ``max_image_size`` resolved (:func:`resolved_image_size`): never None.

    Every check that needs no pixels is here: the folders and model files, the model's cameras, poses and points,
    the image names, each registered image's presence, header and size against its camera (the distorted camera
    for distorted models), and the sparse points depth ranges need. Raises :class:`DeepCError` naming the file.
    """
    options = (options or SceneOptions()).validate()
    root = Path(path)
    if not root.is_dir():
        raise DeepCError("scene folder not found" if not root.exists() else "not a folder", root)
    if not (root / "images").is_dir():
        raise DeepCError("no images/ folder: a scene is a COLMAP workspace with images/ and sparse/", root)
    model_dir = find_model_dir(root)
    model = read_sparse_model(model_dir)
    image_root = root / "images"
    sizes = []
    for im in model.images:
        if Path(im.name).is_absolute() or ".." in Path(im.name).parts:
            # outputs are named after images: such a name would write outside the output folder
            raise DeepCError(f"image name {im.name!r} leaves the images/ folder", model_dir)
        if im.camera_id not in model.cameras:
            raise DeepCError(f"image {im.name} refers to camera {im.camera_id}, which the model lacks", model_dir)
        cam = model.cameras[im.camera_id]
        size = image_size(image_root / im.name)  # the header alone
        if size != (cam.width, cam.height):
            kind = "" if cam.model in PINHOLE_MODELS else f" ({cam.model})"
            raise DeepCError(f"image is {size[0]}x{size[1]} but its COLMAP camera {im.camera_id}{kind} is "
                             f"{cam.width}x{cam.height}", image_root / im.name)
        sizes.append(size)
    # the default working size becomes a number here: what the run saves and re-runs with
    options = options.replace(max_image_size=resolved_image_size(options, sizes))

    used = sorted({im.camera_id for im in model.images})
    distorted = sorted({model.cameras[c].model for c in used if model.cameras[c].model not in PINHOLE_MODELS})
    if distorted and not options.undistort:
        raise DeepCError(f"camera model(s) {', '.join(distorted)} need undistortion; only PINHOLE and "
                         "SIMPLE_PINHOLE are used directly (run colmap image_undistorter, or allow undistortion)",
                         model_dir)
    cameras = {}
    for c in used:
        cam = model.cameras[c]
        try:
            cameras[c] = cam if cam.model in PINHOLE_MODELS else undistorted_camera(cam, options.max_image_size)
        except Exception as exc:  # pycolmap maps C++ failures to assorted Python exception types
            raise DeepCError(f"camera {c} ({cam.model}) cannot be undistorted ({' '.join(str(exc).split())[:200]})",
                             model_dir) from None
        pinhole = cameras[c].pinhole()
        if not np.isfinite(pinhole).all() or min(pinhole[:2]) <= 0 or min(cameras[c].width, cameras[c].height) <= 0:
            raise DeepCError(f"camera {c} ({cam.model}) has no usable undistorted camera "
                             f"({cameras[c].width}x{cameras[c].height})", model_dir)
    views, shared = _build_views(model, cameras, options, model_dir)

    gt_depth_paths: list[Path | None] = [None] * len(views)
    gt_dir = root / "ground_truth" / "depth_maps"
    if not distorted and gt_dir.is_dir():  # GT depth maps belong to the distorted images otherwise
        for v in views:
            p = gt_dir / f"{v.name}.bin"
            if p.is_file():
                gt_depth_paths[v.index] = p
    gt_points = root / "ground_truth" / "points.ply"
    return SceneSurvey(root, model_dir, model, cameras, views, shared, distorted, sizes, options, gt_depth_paths,
                       gt_points if gt_points.is_file() else None)


def _build_views(model: SparseModel, cameras: dict[int, SparseCamera], options: SceneOptions,
                 model_dir: Path) -> tuple[list[View], np.ndarray]:
    """Views at the working size of ``model``'s images seen through the pinhole ``cameras``, with their depth ranges
    and source views (Schönberger et al. 2016), and the (n, n) counts of shared sparse points."""
    working = []
    for im in model.images:
        cam = cameras[im.camera_id]
        fx, fy, cx, cy = cam.pinhole()
        full = Camera.from_params(cam.width, cam.height, fx, fy, cx, cy, im.R, im.t)
        working.append(full.rescaled(*rescaled_size(cam.width, cam.height, options.max_image_size)))
    ranges, counts = _depth_ranges(model, working, options, model_dir)
    shared = _shared_counts(model, len(working))
    sources = _source_views(model, working, shared, options)
    views = [View(i, im.name, im.image_id, working[i], (cameras[im.camera_id].width, cameras[im.camera_id].height),
                  ranges[i], sources[i], counts[i]) for i, im in enumerate(model.images)]
    return views, shared


def load_scene(path: str | Path, options: SceneOptions | None = None,
               report: Callable[[str], None] | None = None) -> Scene:
    """Load a COLMAP workspace (``images/``, ``sparse/``, optional ``ground_truth/``).

    Everything :func:`survey_scene` checks is checked before any image is undistorted. Distorted workspaces are
    then undistorted at the working size into a cache (``engine.io.undistort``: in a child process, its log off the
    terminal); ``report`` receives deepc's own progress lines (default: stderr).

    Raises :class:`DeepCError` naming the bad file.
    """
    survey = survey_scene(path, options)
    root, options = survey.root, survey.options
    model, views, shared, image_root = survey.model, survey.views, survey.shared_points, root / "images"
    if survey.distorted:
        undistorted = _undistort(survey, report or _stderr_line)
        model = read_sparse_model(undistorted / "sparse")
        image_root = undistorted / "images"
        if not _same_geometry(model, survey):  # pycolmap's images disagree with the camera computed alone
            views, shared = _build_views(model, model.cameras, options, model.path)
        for v in views:
            size = image_size(image_root / v.name)
            if size != v.original_size:
                raise DeepCError(f"undistorted image is {size[0]}x{size[1]}, its camera "
                                 f"{v.original_size[0]}x{v.original_size[1]}", image_root / v.name)
        if (root / "ground_truth" / "depth_maps").is_dir():
            warnings.warn(f"{root}: cameras {', '.join(survey.distorted)} undistorted into {undistorted}; "
                          "its ground-truth depth maps belong to the distorted images and are ignored", stacklevel=2)
    for v in views:
        if survey.gt_depth_paths[v.index] is not None:
            _check_gt_depth(survey.gt_depth_paths[v.index], v)
    same_order = [v.name for v in views] == [im.name for im in survey.model.images]
    return Scene(root, image_root, model, views, options, shared, list(survey.gt_depth_paths), survey.gt_points_path,
                 list(survey.image_sizes) if same_order else None)


def _stderr_line(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _undistort(survey: SceneSurvey, report: Callable[[str], None]) -> Path:
    """Undistort ``survey``'s workspace into its cache entry (reused when complete), reporting what it does."""
    cached = cached_workspace(survey.cache_root, survey.cache_key())
    if cached is not None:
        return cached
    count = len(survey.model.images)
    report(f"undistorting {count} images ({', '.join(survey.distorted)}) at {survey.undistorted_size()} px "
           f"into {survey.cache_root}")
    live = sys.stderr.isatty() and report is _stderr_line

    def progress(done: int, total: int) -> None:
        if live:
            print(f"\rundistorting: {done}/{total} images", end="", file=sys.stderr, flush=True)

    start = time.monotonic()
    try:
        target = undistort_workspace(survey.root, survey.model_dir, survey.cache_root, key=survey.cache_key(),
                                     max_image_size=survey.options.max_image_size, progress=progress)
    finally:
        if live:
            print(file=sys.stderr, flush=True)
    report(f"undistorted {count} images in {time.monotonic() - start:.1f} s (pycolmap's log: "
           f"{target / LOG_FILE})")
    return target


def _same_geometry(model: SparseModel, survey: SceneSurvey) -> bool:
    """Whether the undistorted ``model`` has the images and cameras :func:`survey_scene` computed."""
    if [im.name for im in model.images] != [im.name for im in survey.model.images]:
        return False
    if len(model.points) != len(survey.model.points):
        return False
    for im in model.images:
        got, want = model.cameras.get(im.camera_id), survey.cameras.get(im.camera_id)
        if got is None or want is None or (got.width, got.height) != (want.width, want.height):
            return False
        if not np.allclose(got.pinhole(), want.pinhole(), rtol=1e-9, atol=1e-9):
            return False
    return True


def _check_gt_depth(path: Path, view: View) -> None:
    """GT depth must have the image's aspect ratio (any resolution) and finite values."""
    gw, gh, channels = read_dense_map_header(path)
    if channels != 1:
        raise DeepCError(f"ground-truth depth must have 1 channel, the file has {channels}", path)
    w, h = view.original_size
    if abs(round(h * gw / w) - gh) > 1 or abs(round(w * gh / h) - gw) > 1:
        raise DeepCError(f"ground-truth depth is {gw}x{gh}, not proportional to the {w}x{h} image", path)
    read_depth_map(path)  # checks finiteness now rather than after a long run


def _depth_ranges(model: SparseModel, cameras: list[Camera], options: SceneOptions,
                  model_dir: Path) -> tuple[list[tuple[float, float]], list[int]]:
    n = len(cameras)
    counts = np.bincount(model.track_image, minlength=n).tolist() if len(model.track_image) else [0] * n
    if options.depth_range is not None:
        return [tuple(map(float, options.depth_range))] * n, counts
    if len(model.points) == 0:
        raise DeepCError("the COLMAP model has no 3D points, and depth ranges and source views come from them: "
                         "triangulate points (e.g. colmap point_triangulator) or give --depth-range MIN,MAX",
                         model_dir)
    lo_p, hi_p = options.depth_percentiles
    (s_lo, s_hi), (r_lo, r_hi) = options.depth_stretch, options.depth_relax
    ranges = []
    for i, cam in enumerate(cameras):
        z = cam.world_to_camera(model.points[model.track_point[model.track_image == i]])[:, 2]
        z = z[z > 0]
        if len(z) < _MIN_POINTS_FOR_RANGE:
            # Too few observations: use every sparse point in front of the camera and inside the image.
            uv, z_all = cam.project(model.points)
            inside = (z_all > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] < cam.width - 0.5) & \
                     (uv[:, 1] >= -0.5) & (uv[:, 1] < cam.height - 0.5)
            z = z_all[inside]
        if len(z) == 0:
            raise DeepCError(f"view {model.images[i].name}: no sparse point lies in front of the camera, so its "
                             "depth range is unknown; give --depth-range MIN,MAX", model_dir)
        z = np.sort(z)
        z_lo = z[int(math.floor(lo_p * len(z)))] * s_lo
        z_hi = z[min(int(math.floor(hi_p * len(z))), len(z) - 1)] * s_hi
        ranges.append((float(z_lo * r_lo), float(z_hi * r_hi)))
    return ranges, counts


def _shared_counts(model: SparseModel, n: int) -> np.ndarray:
    """(n, n) number of sparse points observed by both views."""
    if len(model.track_point) == 0:
        return np.zeros((n, n), np.int64)
    from scipy.sparse import csr_matrix  # lazy: only scene loading needs it

    # sparse points x views: a dense one grows with points x views (160 MB at 400 views of a street sequence)
    pairs = np.unique(np.stack([model.track_point, model.track_image], axis=1), axis=0)  # a point once per view
    incidence = csr_matrix((np.ones(len(pairs), np.int64), (pairs[:, 0], pairs[:, 1])), shape=(len(model.points), n))
    return np.asarray((incidence.T @ incidence).toarray(), np.int64)


def _source_views(model: SparseModel, cameras: list[Camera], shared: np.ndarray,
                  options: SceneOptions) -> list[list[int]]:
    n = len(cameras)
    if len(model.track_point) == 0:
        return _source_views_from_poses(cameras, options.num_source_views)
    angle = triangulation_angle_p75(model, cameras)
    min_angle = math.radians(options.min_triangulation_angle)
    sources = []
    for r in range(n):
        candidates = [j for j in range(n) if j != r and shared[r, j] > 0 and angle[r, j] >= min_angle]
        candidates.sort(key=lambda j: (-shared[r, j], j))
        sources.append(candidates[:options.num_source_views])
    return sources


def triangulation_angle_p75(model: SparseModel, cameras: list[Camera]) -> np.ndarray:
    """(n, n) 75th percentile of the triangulation angles (radians) over the points two views share (a point
    observed twice by a view counts once per pair of observations).

    One view at a time: the pairs of its observations with the other observations of their points (the angles of
    all pairs at once are ~100 bytes per pair: 150 MB at 400 views of a street sequence)."""
    n = len(cameras)
    result = np.zeros((n, n))
    if len(model.track_point) == 0:
        return result
    centers = np.stack([c.center for c in cameras])
    order = np.argsort(model.track_point, kind="stable")
    tp, ti = model.track_point[order], model.track_image[order]
    starts = np.flatnonzero(np.r_[True, tp[1:] != tp[:-1]])
    lengths = np.diff(np.r_[starts, len(tp)])
    track = np.repeat(np.arange(len(starts)), lengths)  # the track of each observation
    by_image = np.argsort(ti, kind="stable")
    bounds = np.searchsorted(ti[by_image], np.arange(n + 1))
    for r in range(n):
        tracks = track[by_image[bounds[r]:bounds[r + 1]]]  # one per observation of view r
        count = lengths[tracks]
        # every observation of those tracks, once per observation of r in the track
        position = np.repeat(starts[tracks] - np.cumsum(count) + count, count) + np.arange(count.sum())
        other = ti[position]
        keep = other > r  # each pair once (r < j); the pairs of r's own observations have no angle
        b, p = other[keep], tp[position[keep]]
        if not len(b):
            continue
        ra = centers[r] - model.points[p]
        rb = centers[b] - model.points[p]
        cos = (np.einsum("ij,ij->i", ra, rb) /
               np.maximum(np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1), 1e-300))
        angles = np.arccos(np.clip(cos, -1.0, 1.0))
        sort = np.lexsort((angles, b))
        b, angles = b[sort], angles[sort]
        edges = np.flatnonzero(np.r_[True, b[1:] != b[:-1], True])
        for s, e in zip(edges[:-1], edges[1:], strict=True):
            result[r, b[s]] = result[b[s], r] = np.percentile(angles[s:e], 75)
    return result


def _source_views_from_poses(cameras: list[Camera], count: int) -> list[list[int]]:
    """Fallback without sparse points: nearest cameras whose optical axes are within 60° of the reference."""
    centers = np.stack([c.center for c in cameras])
    axes = np.stack([c.R[2] for c in cameras])
    sources = []
    for r in range(len(cameras)):
        dist = np.linalg.norm(centers - centers[r], axis=1)
        ok = [j for j in np.argsort(dist, kind="stable") if j != r and axes[j] @ axes[r] > 0.5 and dist[j] > 0]
        sources.append([int(j) for j in ok[:count]])
    return sources
