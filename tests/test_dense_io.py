"""COLMAP dense .bin maps: byte layout, round trips, interop and defects."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from engine.core.errors import DeepCError
from engine.io.dense import (
    encode_dense_map,
    read_dense_map,
    read_dense_map_header,
    read_depth_map,
    read_normal_map,
    write_dense_map,
)


def colmap_documented_bytes(array: np.ndarray) -> bytes:
    """Independent encoder of COLMAP's layout (mat.cc / read_write_dense.py): element (r, c, ch) at
    index ch*W*H + r*W + c, written one float at a time, little endian."""
    if array.ndim == 2:
        array = array[:, :, None]
    h, w, c = array.shape
    out = bytearray(f"{w}&{h}&{c}&".encode())
    for ch in range(c):
        for r in range(h):
            for col in range(w):
                out += struct.pack("<f", float(array[r, col, ch]))
    return bytes(out)


def colmap_documented_read(data: bytes) -> np.ndarray:
    """Independent decoder following read_write_dense.py: header, then Fortran order over (W, H, C)."""
    parts = data.split(b"&", 3)
    w, h, c = (int(p) for p in parts[:3])
    values = np.frombuffer(parts[3], "<f4")
    array = values.reshape((w, h, c), order="F").transpose(1, 0, 2)
    return np.squeeze(array)


@pytest.mark.parametrize("shape", [(7, 5), (6, 9, 3), (1, 1), (4, 3, 2)])
def test_bytes_match_colmap_layout_and_round_trip(tmp_path, shape):
    rng = np.random.default_rng(1)
    array = rng.normal(size=shape).astype(np.float32)
    path = tmp_path / "map.bin"
    write_dense_map(path, array)
    assert path.read_bytes() == colmap_documented_bytes(array)
    np.testing.assert_array_equal(colmap_documented_read(path.read_bytes()), np.squeeze(array))
    back = read_dense_map(path)
    assert back.dtype == np.float32 and back.shape == shape
    np.testing.assert_array_equal(back, array)
    assert read_dense_map_header(path) == (shape[1], shape[0], 1 if len(shape) == 2 else shape[2])


def test_reads_files_written_by_other_tools(tmp_path):
    rng = np.random.default_rng(2)
    normals = rng.normal(size=(10, 12, 3)).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    (tmp_path / "n.bin").write_bytes(colmap_documented_bytes(normals))
    np.testing.assert_array_equal(read_normal_map(tmp_path / "n.bin"), normals)
    # Channel planes must not be interleaved: the first plane holds every pixel's x component.
    raw = np.frombuffer((tmp_path / "n.bin").read_bytes()[len(b"12&10&3&"):], "<f4")
    np.testing.assert_array_equal(raw[:120].reshape(10, 12), normals[:, :, 0])


def test_pycolmap_depth_map_interop(tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    depth = np.random.default_rng(3).uniform(1, 5, size=(9, 13)).astype(np.float32)
    write_dense_map(tmp_path / "ours.bin", depth)
    theirs = pycolmap.DepthMap()
    theirs.read(str(tmp_path / "ours.bin"))
    np.testing.assert_array_equal(theirs.to_array(), depth)
    pycolmap.DepthMap.from_array(depth, 1.0, 5.0).write(str(tmp_path / "theirs.bin"))
    assert (tmp_path / "theirs.bin").read_bytes() == (tmp_path / "ours.bin").read_bytes()


@pytest.mark.parametrize("data,message", [
    (b"", "header"),
    (b"garbage without ampersands", "header"),
    (b"12&x&1&" + bytes(48), "malformed"),
    (b"0&3&1&", "malformed"),
    (b"4&3&1&" + bytes(47), "truncated"),
    (b"4&3&1&" + bytes(49), "after"),
    (b"-4&3&1&" + bytes(48), "malformed"),
])
def test_defective_files_give_one_line_naming_the_file(tmp_path, data, message):
    path = tmp_path / "bad.bin"
    path.write_bytes(data)
    with pytest.raises(DeepCError) as info:
        read_dense_map(path)
    text = str(info.value)
    assert str(path) in text and message in text and "\n" not in text


def test_channel_count_is_checked(tmp_path):
    write_dense_map(tmp_path / "d.bin", np.ones((3, 4), np.float32))
    with pytest.raises(DeepCError, match="3-channel"):
        read_normal_map(tmp_path / "d.bin")


def test_non_finite_depth_is_an_error_unless_allowed(tmp_path):
    depth = np.ones((3, 4), np.float32)
    depth[1, 2] = np.nan
    depth[0, 0] = np.inf
    write_dense_map(tmp_path / "d.bin", depth)
    with pytest.raises(DeepCError, match="2 non-finite"):
        read_depth_map(tmp_path / "d.bin")
    fixed = read_depth_map(tmp_path / "d.bin", allow_nonfinite=True)
    assert fixed[1, 2] == 0 and fixed[0, 0] == 0 and fixed[2, 3] == 1


def test_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    path = tmp_path / "d.bin"
    write_dense_map(path, np.ones((2, 2), np.float32))
    before = path.read_bytes()

    def boom(array):
        raise RuntimeError("disk fell off")
    import engine.io.dense as dense
    monkeypatch.setattr(dense, "encode_dense_map", boom)
    with pytest.raises(RuntimeError):
        dense.write_dense_map(path, np.zeros((2, 2), np.float32))
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.bin"]


def test_encode_rejects_bad_shapes():
    with pytest.raises(ValueError):
        encode_dense_map(np.zeros((2, 2, 2, 2), np.float32))
    with pytest.raises(ValueError):
        encode_dense_map(np.zeros((0, 2), np.float32))
