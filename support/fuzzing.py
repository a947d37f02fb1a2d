"""Fuzzing of every file reader: mutated valid files must either load or raise one clear DeepCError.

A :class:`FuzzTarget` is a valid input (one or more files in a folder), the files a fuzzer may
corrupt, and the reader to call on the folder. :func:`check_input` writes a mutated input, calls the
reader and accepts exactly two outcomes: a result, or :class:`engine.core.errors.DeepCError` whose message
is one line and names a file of the input. Anything else (another exception, a hang that pytest's
timeout catches, a native crash of the test process) is a reader bug.

Mutations (:func:`mutations`) are those that real damage and hostile files produce: truncation
(half-copied files), bit flips, overwritten byte runs, inserted/deleted bytes, huge or negative
binary counts at aligned offsets, and, for text, a numeric token replaced by NaN, inf, a negative,
huge or non-numeric value, or a dropped or duplicated line.

Used by ``tests/test_fuzz_readers.py`` (a bounded number of examples per target, derandomised) and
``benchmarks/reliability/fuzz_readers.py`` (many more, counts written to ``benchmarks/results/fuzz_readers.json``).

Adding a reader is one small function that builds a target, registered in ``TARGETS``::

    def suite_target(tmp: Path) -> FuzzTarget:
        (tmp / "suite.toml").write_text(VALID_SUITE)
        return FuzzTarget("regress_suite", tmp, ["suite.toml"], lambda root: load_suite(root / "suite.toml"),
                          text=True)
"""

from __future__ import annotations

import dataclasses
import re
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import strategies as st

from engine.core.errors import DeepCError

REPO = Path(__file__).resolve().parent.parent
SAMPLES = REPO / "sample_scenes"


@dataclasses.dataclass
class FuzzTarget:
    """One reader under test.

    Attributes:
        name: short id, used for counts and test ids.
        root: folder holding a valid input.
        files: paths (relative to ``root``) a mutation may corrupt.
        read: the reader, called with the folder of a (mutated) copy of the input.
        text: the files are text (enables token and line mutations).
    """

    name: str
    root: Path
    files: list[str]
    read: Callable[[Path], Any]
    text: bool = False


@dataclasses.dataclass
class FuzzCounts:
    """Outcomes of the inputs one target tried."""

    tried: int = 0
    loaded: int = 0
    clear_errors: int = 0
    failures: list[str] = dataclasses.field(default_factory=list)


# ---- mutations -------------------------------------------------------------------------------------
_TOKENS = ["nan", "inf", "-inf", "-1", "0", "1e308", "-1e308", "99999999999999999999", "4294967296", "x", "",
           "1e-320", "18446744073709551615", "2147483648", "3.5"]
_NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", re.IGNORECASE)
_HUGE = [0xFFFFFFFF, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFFFFFFFFFF, 1 << 40, 1 << 62, 0, 1]


@st.composite
def mutations(draw, data: bytes, text: bool = False) -> bytes:
    """A damaged variant of ``data`` (see the module docstring for the kinds)."""
    kinds = ["truncate", "flip", "overwrite", "insert", "delete", "count"]
    if text:
        kinds += ["token", "token", "line"]
    kind = draw(st.sampled_from(kinds))
    n = len(data)
    if n == 0:
        return draw(st.binary(max_size=64))
    out = bytearray(data)
    if kind == "truncate":
        return bytes(out[:draw(st.integers(0, n - 1))])
    if kind == "flip":
        for _ in range(draw(st.integers(1, 8))):
            i = draw(st.integers(0, n - 1))
            out[i] ^= 1 << draw(st.integers(0, 7))
        return bytes(out)
    if kind == "overwrite":
        i = draw(st.integers(0, n - 1))
        patch = draw(st.binary(min_size=1, max_size=16))
        out[i:i + len(patch)] = patch
        return bytes(out)
    if kind == "insert":
        i = draw(st.integers(0, n))
        return bytes(out[:i]) + draw(st.binary(min_size=1, max_size=32)) + bytes(out[i:])
    if kind == "delete":
        i = draw(st.integers(0, n - 1))
        return bytes(out[:i]) + bytes(out[i + draw(st.integers(1, 32)):])
    if kind == "count":  # a huge/odd integer where a binary count or id may live
        width = draw(st.sampled_from([4, 8]))
        if n < width:
            return bytes(out[:-1])
        i = draw(st.integers(0, (n - width) // width)) * width
        value = draw(st.sampled_from(_HUGE)) & ((1 << (8 * width)) - 1)
        out[i:i + width] = value.to_bytes(width, "little")
        return bytes(out)
    if kind == "token":
        numbers = list(_NUMBER.finditer(data[:1 << 16]))
        if not numbers:
            return bytes(out[:-1])
        m = numbers[draw(st.integers(0, len(numbers) - 1))]
        return data[:m.start()] + draw(st.sampled_from(_TOKENS)).encode() + data[m.end():]
    lines = data.split(b"\n")  # kind == "line"
    i = draw(st.integers(0, len(lines) - 1))
    if draw(st.booleans()):
        del lines[i]
    else:
        lines.insert(i, lines[i])
    return b"\n".join(lines)


@st.composite
def damaged_inputs(draw, target: FuzzTarget) -> dict[str, bytes]:
    """{relative path: new bytes} for one or two damaged files of ``target``."""
    names = draw(st.lists(st.sampled_from(target.files), min_size=1, max_size=2, unique=True))
    return {name: draw(mutations((target.root / name).read_bytes(), target.text)) for name in names}


# ---- running one input -----------------------------------------------------------------------------
def materialise(target: FuzzTarget, damage: dict[str, bytes], folder: Path) -> Path:
    """A copy of the target's input in ``folder`` with ``damage`` applied; everything else is symlinked."""
    def fill(src: Path, dst: Path, rel: str) -> None:
        dst.mkdir(parents=True, exist_ok=True)
        for entry in src.iterdir():
            name = f"{rel}{entry.name}"
            if name in damage:
                (dst / entry.name).write_bytes(damage[name])
            elif any(d.startswith(name + "/") for d in damage):
                fill(entry, dst / entry.name, name + "/")
            else:
                (dst / entry.name).symlink_to(entry.resolve(), target_is_directory=entry.is_dir())

    fill(target.root, folder, "")
    return folder


def check_input(target: FuzzTarget, damage: dict[str, bytes], counts: FuzzCounts | None = None) -> str:
    """Run the reader on a damaged input; returns "loaded" or "error". Raises AssertionError on a bad
    outcome: an exception that is not a DeepCError, or a DeepCError that is not one line naming a file
    of the input."""
    with tempfile.TemporaryDirectory(prefix=f"fuzz-{target.name}-") as tmp:
        folder = materialise(target, damage, Path(tmp))
        if counts is not None:
            counts.tried += 1
        try:
            target.read(folder)
        except DeepCError as exc:
            message = str(exc)
            ok = "\n" not in message and tmp in message
            if not ok:
                _fail(counts, f"{target.name}: unclear error {message!r} for damage of {sorted(damage)}")
            if counts is not None:
                counts.clear_errors += 1
            return "error"
        except Exception as exc:  # noqa: BLE001  (any other exception is the bug being hunted)
            _fail(counts, f"{target.name}: {type(exc).__name__}: {exc!s:.300} for damage of {sorted(damage)}")
        if counts is not None:
            counts.loaded += 1
        return "loaded"


def _fail(counts: FuzzCounts | None, text: str) -> None:
    if counts is not None:
        counts.failures.append(text)
    raise AssertionError(text)


# ---- targets ---------------------------------------------------------------------------------------
def dense_target(tmp: Path) -> FuzzTarget:
    """Dense .bin maps: a depth map (1 channel) and a normal map (3 channels), read as the engine reads them."""
    from engine.io.dense import read_dense_map_header, read_depth_map, read_normal_map, write_dense_map

    rng = np.random.default_rng(0)
    write_dense_map(tmp / "depth.bin", rng.uniform(1, 5, (12, 16)).astype(np.float32))
    normal = rng.normal(size=(12, 16, 3)).astype(np.float32)
    write_dense_map(tmp / "normal.bin", normal / np.linalg.norm(normal, axis=2, keepdims=True))

    def read(root: Path) -> None:
        read_dense_map_header(root / "depth.bin")
        read_depth_map(root / "depth.bin")
        read_normal_map(root / "normal.bin")

    return FuzzTarget("dense_bin", tmp, ["depth.bin", "normal.bin"], read)


def _ply_files(tmp: Path) -> None:
    from engine.io.ply import write_ply

    rng = np.random.default_rng(1)
    xyz = rng.normal(size=(40, 3))
    write_ply(tmp / "binary.ply", xyz, rng.normal(size=(40, 3)), rng.integers(0, 255, (40, 3)))
    header = "ply\nformat {} 1.0\nelement face 1\nproperty list uchar int vertex_indices\n" \
             "element vertex 6\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nend_header\n"
    rows = "".join(f"{x:.4f} {y:.4f} {z:.4f} {i * 10}\n" for i, (x, y, z) in enumerate(xyz[:6]))
    (tmp / "ascii.ply").write_text(header.replace("element face 1\nproperty list uchar int vertex_indices\n", "")
                                   .format("ascii") + rows)
    table = np.zeros(6, np.dtype([("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("red", "u1")]))
    table["x"], table["y"], table["z"] = xyz[:6].T
    big = header.replace("element face 1\nproperty list uchar int vertex_indices\n", "").format("binary_big_endian")
    (tmp / "big.ply").write_bytes(big.encode() + table.tobytes())
    # OpenMVS's dense cloud: per-point lists of view indices and weights after the scalars
    lists = (b"ply\nformat binary_little_endian 1.0\nelement vertex 6\nproperty float x\nproperty float y\n"
             b"property float z\nproperty list uint8 uint32 view_indices\nproperty list uint8 float32 view_weights\n"
             b"end_header\n")
    for i, point in enumerate(xyz[:6].astype("<f4")):
        lists += point.tobytes() + bytes([i % 4]) + np.arange(i % 4, dtype="<u4").tobytes() \
            + bytes([i % 4]) + np.full(i % 4, 0.5, "<f4").tobytes()
    (tmp / "lists.ply").write_bytes(lists)


def ply_target(tmp: Path) -> FuzzTarget:
    """PLY: binary little endian (as we write), ASCII, big-endian binary and OpenMVS's vertex lists."""
    from engine.io.ply import read_ply

    _ply_files(tmp)

    def read(root: Path) -> None:
        for name in ("binary.ply", "ascii.ply", "big.ply", "lists.ply"):
            read_ply(root / name)

    return FuzzTarget("ply", tmp, ["binary.ply", "ascii.ply", "big.ply", "lists.ply"], read)


def _scene_copy(tmp: Path, scene: str) -> Path:
    src = SAMPLES / scene
    shutil.copytree(src / "sparse", tmp / "sparse")
    (tmp / "images").symlink_to(src / "images", target_is_directory=True)
    return tmp


def colmap_text_target(tmp: Path) -> FuzzTarget:
    """COLMAP text model (tiny scene) through load_scene: pycolmap plus our checks."""
    from engine.scene import load_scene

    _scene_copy(tmp, "tiny")
    files = sorted(f"sparse/{p.name}" for p in (tmp / "sparse").iterdir())
    return FuzzTarget("colmap_text", tmp, files, lambda root: load_scene(root), text=True)


def colmap_binary_target(tmp: Path) -> FuzzTarget:
    """COLMAP binary model (small scene) through load_scene."""
    from engine.scene import load_scene

    _scene_copy(tmp, "small")
    files = sorted(f"sparse/{p.name}" for p in (tmp / "sparse").iterdir())
    return FuzzTarget("colmap_binary", tmp, files, lambda root: load_scene(root))


def eth3d_mlp_target(tmp: Path) -> FuzzTarget:
    """ETH3D scan_alignment.mlp (MeshLab XML) with two scans."""
    from engine.evaluation import load_eth3d_mlp
    from engine.io.ply import write_ply

    rng = np.random.default_rng(2)
    for name in ("scan1.ply", "scan2.ply"):
        write_ply(tmp / name, rng.normal(size=(30, 3)))
    mesh = ('  <MLMesh label="{0}" filename="{0}">\n   <MLMatrix44>\n{1}</MLMatrix44>\n  </MLMesh>\n')
    pose = "1 0 0 0.5 \n0 1 0 -0.25 \n0 0 1 2 \n0 0 0 1 \n"
    (tmp / "scan_alignment.mlp").write_text(
        '<!DOCTYPE MeshLabDocument>\n<MeshLabProject>\n <MeshGroup>\n' + mesh.format("scan1.ply", pose)
        + mesh.format("scan2.ply", pose) + ' </MeshGroup>\n <RasterGroup/>\n</MeshLabProject>\n')
    return FuzzTarget("eth3d_mlp", tmp, ["scan_alignment.mlp"],
                      lambda root: load_eth3d_mlp(root / "scan_alignment.mlp"), text=True)


def images_target(tmp: Path) -> FuzzTarget:
    """Images as the scene reads them (header size, then pixels): PNG and JPEG."""
    from PIL import Image

    from engine.io.images import image_size, read_image

    rng = np.random.default_rng(3)
    pixels = rng.integers(0, 255, (24, 32, 3), dtype=np.uint8)
    Image.fromarray(pixels).save(tmp / "view.png")
    Image.fromarray(pixels).save(tmp / "view.jpg", quality=80)

    def read(root: Path) -> None:
        for name in ("view.png", "view.jpg"):
            image_size(root / name)
            read_image(root / name)

    return FuzzTarget("images", tmp, ["view.png", "view.jpg"], read)


def regress_suite_target(tmp: Path) -> FuzzTarget:
    """Regression suite TOML (workbench.regress.suite.load_suite): every key kind, parsed as ``deepc regress`` does."""
    from workbench.regress import load_suite

    for scene in ("tiny", "small"):  # load_suite checks that each scene folder has sparse/
        (tmp / scene).symlink_to(SAMPLES / scene, target_is_directory=True)
    (tmp / "suite.toml").write_text(VALID_SUITE)
    return FuzzTarget("regress_suite", tmp, ["suite.toml"], lambda root: load_suite(root / "suite.toml"),
                      text=True)


VALID_SUITE = """name = "fuzz"
baseline = "baselines"
thumbnail_views = 4

[defaults]
schedule = "acmm"
seed = 0
max-image-size = 160

[tolerances]
f1 = 0.5
time = 0.5

[[scene]]
path = "tiny"
plane-propagation = false

[[scene]]
path = "small"
name = "small-192"
max-image-size = 192
tolerances = { accuracy = 1.0 }

[[pipeline]]
name = "vanilla"
pipeline = "vanilla"
set = ["patchmatch.iterations=2", "patchmatch.window=7"]

[[pipeline]]
name = "fast"
pipeline = "fast"
scenes = ["tiny"]
tolerances = { auc = 1.0, cpu_time = false }
"""


def confidence_weights_target(tmp: Path) -> FuzzTarget:
    """Confidence-network weights file (engine/confidence/weights.py load_weights) in the shipped format:
    a tiny network (widths 2, 4; 30 KB instead of 15 MB) so that each mutation is cheap to load."""
    from engine.confidence.network import ConfidenceNet
    from engine.confidence.weights import load_weights, save_weights

    torch = __import__("torch")
    torch.manual_seed(0)
    save_weights(tmp / "weights.pt", ConfidenceNet("middle", (2, 4)), {"val_auc": 80.5, "note": "fuzz"})
    return FuzzTarget("confidence_weights", tmp, ["weights.pt"], lambda root: load_weights(root / "weights.pt"))


def dmap_target(tmp: Path) -> FuzzTarget:
    """OpenMVS depth-data files (``engine.compare.dmap``): one with every map, one with depth alone."""
    from engine.compare.dmap import read_dmap
    from support.foreign_runs import encode_dmap

    rng = np.random.default_rng(2)
    depth = rng.uniform(1, 5, (6, 8)).astype(np.float32)
    full = encode_dmap("../images/a.png", depth, normal=rng.normal(size=(6, 8, 3)),
                       confidence=rng.uniform(0, 1, (6, 8)), views=rng.integers(0, 9, (6, 8, 4)), view_ids=(0, 3, 4))
    (tmp / "depth0000.dmap").write_bytes(full)
    (tmp / "depth0001.dmap").write_bytes(encode_dmap("b.png", depth))

    def read(root: Path) -> None:
        for name in ("depth0000.dmap", "depth0001.dmap"):
            read_dmap(root / name)

    return FuzzTarget("openmvs_dmap", tmp, ["depth0000.dmap", "depth0001.dmap"], read)


TARGETS: dict[str, Callable[[Path], FuzzTarget]] = {
    "dense_bin": dense_target,
    "ply": ply_target,
    "colmap_text": colmap_text_target,
    "colmap_binary": colmap_binary_target,
    "eth3d_mlp": eth3d_mlp_target,
    "images": images_target,
    "regress_suite": regress_suite_target,
    "confidence_weights": confidence_weights_target,
    "openmvs_dmap": dmap_target,
}
