"""Make the small copies of real scenes shipped in ``sample_scenes/`` from ``../shared/data``.

    python sample_scenes/make_real_copies.py [--data ../shared/data] [--out sample_scenes]

- ``fountain_p11``: 11 views at 384×256 (1/4 of 1536×1024), GT depth maps at that size (lower median
  of the valid depths of each 4×4 block), GT points.ply unchanged (world frame).
- ``middlebury_temple``: 16 views at 320×240 (1/2 of 640×480), no ground truth.

Images are area-averaged; intrinsics and keypoints are scaled exactly (continuous coordinates scale
by the size ratio). The model keeps only the 2-D observations that belong to a 3-D point, so the
copies stay small. Each copy keeps its original README (provenance, citation) with a note on top.
Output is written to a temporary folder and renamed into place.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pycolmap
from PIL import Image

from engine.core.resample import resample_depth
from engine.io.dense import read_depth_map, write_dense_map

# name: (source folder, downscale factor, binary model?) - one binary and one text model, so both
# readers are exercised by the shipped scenes.
COPIES = {
    "fountain_p11": ("fountain_p11", 4, True),
    "middlebury_temple": ("middlebury_temple_sparse_ring", 2, False),
}


def scaled_model(src: pycolmap.Reconstruction, factor: int) -> pycolmap.Reconstruction:
    """The model for images downscaled by ``factor``, keeping only observed keypoints."""
    out = pycolmap.Reconstruction()
    for cam in src.cameras.values():
        params = np.array(cam.params, np.float64) / factor
        out.add_camera_with_trivial_rig(pycolmap.Camera(
            model=cam.model.name, width=cam.width // factor, height=cam.height // factor,
            params=params.tolist(), camera_id=cam.camera_id))
    remap: dict[tuple[int, int], int] = {}
    for image_id in sorted(src.images):
        im = src.images[image_id]
        kept = []
        for idx, p2d in enumerate(im.points2D):
            if p2d.has_point3D():
                remap[(image_id, idx)] = len(kept)
                kept.append(pycolmap.Point2D(np.asarray(p2d.xy) / factor))
        new = pycolmap.Image(name=im.name, camera_id=im.camera_id, image_id=image_id)
        new.points2D = pycolmap.Point2DList(kept)
        out.add_image_with_trivial_frame(new, im.cam_from_world())
    for point in src.points3D.values():
        track = pycolmap.Track([pycolmap.TrackElement(e.image_id, remap[(e.image_id, e.point2D_idx)])
                                for e in point.track.elements])
        out.add_point3D(point.xyz, track, point.color)
    return out


def make_copy(name: str, data_root: Path, out_root: Path) -> None:
    source_name, factor, binary = COPIES[name]
    src_root = data_root / source_name
    target = out_root / name
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=out_root))
    try:
        model = pycolmap.Reconstruction(str(src_root / "sparse"))
        (tmp / "sparse").mkdir()
        small_model = scaled_model(model, factor)
        (small_model.write_binary if binary else small_model.write_text)(str(tmp / "sparse"))
        for im in model.images.values():
            dst = tmp / "images" / im.name
            dst.parent.mkdir(parents=True, exist_ok=True)
            with Image.open(src_root / "images" / im.name) as image:
                small = image.convert("RGB").resize((image.width // factor, image.height // factor), Image.BOX)
            if dst.suffix.lower() in (".jpg", ".jpeg"):
                small.save(dst, quality=95, subsampling=0)
            else:
                small.save(dst)
            gt = src_root / "ground_truth" / "depth_maps" / f"{im.name}.bin"
            if gt.is_file():
                depth = read_depth_map(gt)
                small_depth = resample_depth(depth, (depth.shape[1] // factor, depth.shape[0] // factor))
                write_dense_map(tmp / "ground_truth" / "depth_maps" / f"{im.name}.bin", small_depth)
        if (src_root / "ground_truth" / "points.ply").is_file():
            shutil.copyfile(src_root / "ground_truth" / "points.ply", tmp / "ground_truth" / "points.ply")
        note = (f"DeepC Workbench sample copy of '{source_name}': images downscaled by {factor} (area average), "
                f"intrinsics and keypoints scaled by 1/{factor}, only keypoints with a 3-D point kept"
                + (", GT depth maps downscaled (lower median of valid depths per block), points.ply unchanged"
                   if (src_root / "ground_truth").is_dir() else "")
                + ". Made by sample_scenes/make_real_copies.py. The original README follows.\n\n")
        (tmp / "README.txt").write_text(note + (src_root / "README.txt").read_text())
        if target.exists():
            shutil.rmtree(target)
        tmp.rename(target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def main() -> None:
    here = Path(__file__).resolve().parent
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=here.parent.parent / "shared" / "data")
    parser.add_argument("--out", type=Path, default=here)
    parser.add_argument("--only", choices=sorted(COPIES))
    args = parser.parse_args()
    for name in [args.only] if args.only else sorted(COPIES):
        make_copy(name, args.data, args.out)
        print(f"wrote {args.out / name}")


if __name__ == "__main__":
    main()
