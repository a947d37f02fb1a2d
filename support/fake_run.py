"""A fake ``deepc run`` output made from a scene's GT depth: viewer tests and viewer benchmarks without PatchMatch."""

from __future__ import annotations

from pathlib import Path


def make_fake_run(scene_dir: Path, out_dir: Path, with_confidence: bool = True, scene_options=None) -> Path:
    """An output folder as `deepc run` writes it, made from GT depth instead of PatchMatch, so that
    viewer tests are fast. Confidence ramps from 0 (top row) to 1 (bottom row) and the counter from
    0 to 5, so every move of a filter threshold visibly removes or restores points."""
    import numpy as np

    from engine.run.folder import write_map, write_metrics
    from engine.scene import load_scene
    from support.gt_normals import depth_normals

    scene = load_scene(scene_dir, scene_options)
    for v in scene.views:
        depth = scene.gt_depth(v.index).copy()
        h, w = depth.shape
        ramp = np.repeat((np.arange(h, dtype=np.float32) / (h - 1))[:, None], w, axis=1)
        normal = depth_normals(v.camera, depth)
        depth[~normal.any(axis=2)] = 0
        write_map(out_dir, "depth", v.name, depth)
        write_map(out_dir, "normal", v.name, normal)
        write_map(out_dir, "counter", v.name, np.floor(ramp * 5.99) * (depth > 0))
        write_map(out_dir, "cost", v.name, 1.0 - ramp)
        if with_confidence:
            write_map(out_dir, "confidence", v.name, ramp)
    write_metrics(out_dir, {"scene": scene.name, "scene_path": str(scene_dir.resolve()), "pipeline": "fast",
                            "num_images": len(scene.views), "options": {"scene": scene.options.to_dict()}})
    return out_dir
