"""PLY reading and writing."""

from __future__ import annotations

import numpy as np
import pytest

from engine.core.errors import DeepCError
from engine.io.ply import read_ply, read_points, write_ply


def test_round_trip_with_normals_colours_and_extras(tmp_path):
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(50, 3))
    normals = rng.normal(size=(50, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, size=(50, 3)).astype(np.uint8)
    views = rng.integers(0, 9, size=50).astype(np.uint16)
    write_ply(tmp_path / "a.ply", xyz, normals, rgb, extra={"num_views": views})
    columns = read_ply(tmp_path / "a.ply")
    assert columns["x"].dtype == np.float32  # ETH3D's evaluator needs float, not double
    np.testing.assert_allclose(read_points(tmp_path / "a.ply"), xyz, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(columns["red"], rgb[:, 0])
    np.testing.assert_array_equal(columns["num_views"], views)
    np.testing.assert_array_equal(columns["nz"], normals[:, 2])


def test_double_coordinates_and_big_endian_and_ascii_are_read(tmp_path):
    xyz = np.array([[1.5, -2.25, 3.0], [4.0, 5.0, 6.125]])
    write_ply(tmp_path / "d.ply", xyz, coordinate_dtype="f8")
    np.testing.assert_array_equal(read_points(tmp_path / "d.ply"), xyz)
    header = b"ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\n" \
             b"property float z\nend_header\n"
    (tmp_path / "b.ply").write_bytes(header + xyz.astype(">f4").tobytes())
    np.testing.assert_array_equal(read_points(tmp_path / "b.ply"), xyz)
    text = "ply\nformat ascii 1.0\ncomment hi\nelement vertex 2\nproperty float x\nproperty float y\n" \
           "property float z\nproperty uchar red\nelement face 0\nproperty list uchar int vertex_indices\n" \
           "end_header\n1.5 -2.25 3 255\n4 5 6.125 0\n"
    (tmp_path / "a.ply").write_text(text)
    np.testing.assert_array_equal(read_points(tmp_path / "a.ply"), xyz)


def test_empty_cloud_is_valid(tmp_path):
    write_ply(tmp_path / "e.ply", np.zeros((0, 3)))
    assert read_points(tmp_path / "e.ply").shape == (0, 3)


@pytest.mark.parametrize("content,message", [
    (b"not a ply", "not a PLY"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "end_header"),
    (b"ply\nformat ascii 1.0\nelement face 1\nproperty float x\nend_header\n1\n", "no 'vertex'"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n", "no z"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
     b"property float z\nend_header\n" + bytes(12), "truncated"),
    (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
     b"end_header\n1 2 3\n", "truncated"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
     b"end_header\n1 a 3\n", "malformed"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quaternion x\nend_header\n", "malformed"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
     b"end_header\nnan 1 1\n", "non-finite"),
])
def test_defective_ply_gives_one_line_naming_the_file(tmp_path, content, message):
    path = tmp_path / "bad.ply"
    path.write_bytes(content)
    with pytest.raises(DeepCError) as info:
        read_ply(path)
    assert str(path) in str(info.value) and message in str(info.value) and "\n" not in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(DeepCError, match="not found"):
        read_ply(tmp_path / "nope.ply")
