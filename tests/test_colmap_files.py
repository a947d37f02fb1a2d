"""COLMAP models read with numpy: the same cameras, poses (to the last bit), points and tracks as pycolmap, in
binary and text; a model with a multi-sensor rig is left to pycolmap; `deepc info` never loads pycolmap."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from engine.core.errors import DeepCError
from engine.io import colmap_model
from engine.io.colmap_files import read_model_files
from engine.io.colmap_model import read_sparse_model

REPO = Path(__file__).resolve().parent.parent
SAMPLES = [REPO / "sample_scenes" / name / "sparse" for name in ("tiny", "small")]


def _through_pycolmap(model_dir: Path, monkeypatch: pytest.MonkeyPatch) -> colmap_model.SparseModel:
    with monkeypatch.context() as patch:
        patch.setattr(colmap_model, "read_model_files", lambda path: None)
        return read_sparse_model(model_dir)


def _assert_same(a: colmap_model.SparseModel, b: colmap_model.SparseModel) -> None:
    assert a.cameras.keys() == b.cameras.keys()
    for key, cam in a.cameras.items():
        other = b.cameras[key]
        assert (cam.model, cam.width, cam.height) == (other.model, other.width, other.height)
        np.testing.assert_array_equal(cam.params, other.params)
    assert [(i.image_id, i.name, i.camera_id) for i in a.images] == [(i.image_id, i.name, i.camera_id)
                                                                     for i in b.images]
    for x, y in zip(a.images, b.images, strict=True):
        np.testing.assert_array_equal(x.R, y.R)  # bit for bit: the maps of a run must not depend on the reader
        np.testing.assert_array_equal(x.t, y.t)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.track_point, b.track_point)
    np.testing.assert_array_equal(a.track_image, b.track_image)


@pytest.mark.parametrize("sample", SAMPLES, ids=lambda p: p.parent.name)
@pytest.mark.parametrize("binary", [False, True], ids=["text", "binary"])
def test_numpy_reader_matches_pycolmap(sample: Path, binary: bool, tmp_path: Path,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    import pycolmap

    model_dir = sample
    if binary:
        pycolmap.Reconstruction(str(sample)).write_binary(str(tmp_path))
        model_dir = tmp_path
        assert (tmp_path / "images.bin").is_file()
    _assert_same(read_sparse_model(model_dir), _through_pycolmap(model_dir, monkeypatch))


def test_unregistered_observations_and_image_names_with_spaces(tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """A track element of an image the model does not list is dropped, as pycolmap drops it; names keep spaces."""
    (tmp_path / "cameras.txt").write_text("# c\n1 PINHOLE 64 48 50 50 32 24\n")
    (tmp_path / "images.txt").write_text("# i\n3 1 0 0 0 0.1 0 0 1 my photo.png\n1 2 3 -1 2 4 -1\n"
                                         "1 1 0 0 0 0 0 0 1 a.png\n\n")
    (tmp_path / "points3D.txt").write_text("7 0 0 5 1 2 3 0.5 3 0 1 0 9 0\n2 1 1 6 1 2 3 0.5 1 0\n")
    model = read_sparse_model(tmp_path)
    assert [i.name for i in model.images] == ["a.png", "my photo.png"]  # by image id
    np.testing.assert_array_equal(model.points, [[1, 1, 6], [0, 0, 5]])  # by point id
    # point 2 seen by image 1; point 7 by images 3 and 1 (image 9 is not in the model)
    assert model.track_point.tolist() == [0, 1, 1] and model.track_image.tolist() == [0, 1, 0]


def test_a_multi_sensor_rig_is_read_by_pycolmap(tmp_path: Path) -> None:
    (tmp_path / "rigs.txt").write_text("1 2 CAMERA 1 CAMERA 2 0\n")
    for name in ("cameras", "images", "points3D"):
        (tmp_path / f"{name}.txt").write_text("")
    assert read_model_files(tmp_path) is None


def test_malformed_text_names_the_file_and_line(tmp_path: Path) -> None:
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 64 48 50 50 32\n")  # one parameter short
    (tmp_path / "images.txt").write_text("")
    (tmp_path / "points3D.txt").write_text("")
    with pytest.raises(DeepCError, match=r"cameras.txt: malformed COLMAP model: line 1: PINHOLE takes 4"):
        read_sparse_model(tmp_path)


def test_deepc_info_does_not_load_pycolmap() -> None:
    """pycolmap's 55 MiB stay out of a run on a pinhole workspace (the numpy reader does the work)."""
    code = ("import sys; from workbench.cli.main import main; rc = main(['info', 'sample_scenes/tiny']); "
            "print('PYCOLMAP', 'pycolmap' in sys.modules); sys.exit(rc)")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "PYCOLMAP False" in proc.stdout
