"""Every numba kernel of engine.patchmatch against its plain-Python reference, on small random inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

import support.patchmatch_reference as ref
from engine.core.camera import Camera
from engine.patchmatch import PatchMatchOptions, ViewState, kernel_params, run_view_level
from engine.patchmatch import kernels as K
from engine.patchmatch.context import FINE_CREASE, FINE_EDGE, build_context, depth_edge_band, fine_window_region
from engine.patchmatch.geometry import (
    pack_geometry,
    perturb_normal,
    propagate_depth,
    random_normal,
    ray,
    relative_geometry,
)
from engine.patchmatch.ncc import bilateral_moments, load_window, ncc_cost, ncc_work, pad_sources, window_offsets_2d
from engine.patchmatch.propagation import sampling_pattern
from engine.patchmatch.pyramid import area_resize, jbu_upsample
from engine.patchmatch.rng import combine, stream_key, uniform
from engine.patchmatch.view_pass import half_step, init_cost, n_regions, pattern_of
from engine.patchmatch.view_selection import view_weights

WIN, SIDX = ncc_work(128)  # working arrays of the cost functions (windows of up to 128 samples)


def _smooth_noise(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    img = rng.random((h + 2, w + 2))
    img = (img[:-2, :-2] + img[1:-1, 1:-1] + img[2:, 2:] + img[1:-1, :-2] + img[:-2, 1:-1]) / 5
    return img.astype(np.float32)


def _mixed_texture(img: np.ndarray) -> np.ndarray:
    """The image with its left third at 15 % contrast: weak texture there (standard window), strong
    texture elsewhere (fine window), so kernel tests cover both window sets."""
    out = img.copy()
    third = img.shape[1] // 3
    out[:, :third] = 0.5 + 0.15 * (img[:, :third] - 0.5)
    return out


def _cameras(w: int = 24, h: int = 20) -> tuple[Camera, Camera]:
    a = Camera.from_params(w, h, 22.0, 23.0, w / 2, h / 2)
    yaw = 0.08
    R = np.array([[math.cos(yaw), 0, -math.sin(yaw)], [0, 1, 0], [math.sin(yaw), 0, math.cos(yaw)]])
    b = Camera.from_params(w, h, 21.0, 21.5, w / 2 + 0.7, h / 2 - 0.4, R, np.array([-0.4, 0.05, 0.02]))
    return a, b


@pytest.mark.parametrize("weighting,sigma_c", [("colmap", 0.2), ("acmm", 3.0)])
def test_bilateral_moments_match_reference(weighting: str, sigma_c: float) -> None:
    rng = np.random.default_rng(0)
    img = _smooth_noise(rng, 13, 17)
    offs = window_offsets_2d([-5, -3, -1, 1, 3, 5])
    wgt, wa, mu, var = bilateral_moments(img, offs, weighting, 5.0, sigma_c)
    for y, x in [(0, 0), (6, 8), (12, 16), (3, 15)]:
        w_ref, a_ref = ref.bilateral_weights_ref(img, x, y, offs, weighting, 5.0, sigma_c)
        np.testing.assert_allclose(wgt[y, x], w_ref, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(wa[y, x], w_ref * a_ref, rtol=1e-5, atol=1e-7)
        assert mu[y, x] == pytest.approx((w_ref * a_ref).sum(), abs=1e-6)
        assert var[y, x] == pytest.approx((w_ref * a_ref**2).sum() - (w_ref * a_ref).sum() ** 2, abs=1e-6)


@pytest.mark.parametrize("step", [1, 2])
def test_ncc_cost_matches_reference(step: int) -> None:
    rng = np.random.default_rng(1)
    ref_img, src_img = _smooth_noise(rng, 20, 24), _smooth_noise(rng, 18, 26)
    offs1 = list(range(-5, 6, step))
    offs = window_offsets_2d(offs1)
    wgt, wa, mu, var = bilateral_moments(ref_img, offs, "colmap", 5.0, 0.2)
    stack, sizes = pad_sources([src_img])
    ox, oy = offs[:, 0].astype(np.float32), offs[:, 1].astype(np.float32)
    n_two = 0
    for _ in range(150):
        H = np.eye(3) + rng.normal(0, [[0.05, 0.05, 2], [0.05, 0.05, 2], [1e-3, 1e-3, 0.05]])
        H32 = H.astype(np.float32)
        x, y = int(rng.integers(0, 24)), int(rng.integers(0, 20))
        n = load_window(WIN, ref_img, offs[None], np.array([[5.0, 0.2]]), 0, ox[None], oy[None],
                        np.zeros((20, 24), np.uint8), np.array([len(ox)]), x, y)
        assert n == len(ox)
        np.testing.assert_array_equal(WIN[0, :n], wgt[y, x])  # the weights the moments were computed with
        got = ncc_cost(stack.ravel(), 0, stack.shape[2], 26, 18, WIN, n, mu[y, x], var[y, x], x, y, *H32.ravel(),
                       np.float32(1e-5), SIDX)
        want = ref.ncc_cost_ref(ref_img, src_img, H32.astype(np.float64), x, y, offs)
        assert got == pytest.approx(want, abs=2e-4)
        n_two += want == 2.0
    assert n_two < 150  # most windows were really compared


def test_homography_and_photometric_cost_match_reference() -> None:
    rng = np.random.default_rng(2)
    a, b = _cameras()
    img_a, img_b = _mixed_texture(_smooth_noise(rng, 20, 24)), _mixed_texture(_smooth_noise(rng, 20, 24))
    opts = PatchMatchOptions(fine_window=5)
    ctx = build_context(img_a, a, [img_b], [b], opts)
    assert 0 < ctx.wset.mean() < 1  # both windows in use
    for _ in range(80):
        x, y = int(rng.integers(0, 24)), int(rng.integers(0, 20))
        z = float(rng.uniform(2, 6))
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        rp = np.array(ray(ctx.kinv, x, y))
        if n @ rp > 0:
            n = -n
        H = ref.homography_ref(a.K_idx, a.R, a.t, b.K_idx, b.R, b.t, x, y, z, n)
        offsets, sigma_s, sigma_c = ref.window_choice_ref(img_a.astype(np.float64), x, y, opts)
        want = ref.ncc_cost_ref(img_a, img_b, H.astype(np.float32).astype(np.float64), x, y, offsets, "colmap",
                                sigma_s, sigma_c)
        from engine.patchmatch.geometry import plane_vector

        m0, m1, m2, ok = plane_vector(ctx.kinv, tuple(rp), z, *n)
        assert ok
        n_samples = ctx.window_at(x, y, WIN)
        assert n_samples == len(offsets)
        got = K.photometric_cost(ctx.flat, ctx.stride, ctx.plane, ctx.geo, 0, WIN, n_samples, ctx.mu_a[y, x],
                                 ctx.var_a[y, x], x, y, m0, m1, m2, 1e-5, SIDX)
        assert got == pytest.approx(want, abs=5e-4)


def _checker_texture(img: np.ndarray, period: int = 6) -> np.ndarray:
    """The image with its right third replaced by a two-tone checker (piecewise-constant texture)."""
    out = img.copy()
    h, w = img.shape
    yy, xx = np.mgrid[0:h, 0:w]
    checker = np.where((yy // period + xx // period) % 2 == 0, 0.3, 0.7).astype(np.float32)
    out[:, 2 * w // 3:] = checker[:, 2 * w // 3:]
    return out


@pytest.mark.parametrize("weighting,ratio", [("colmap", 0.0), ("acmm", 0.0), ("colmap", 0.1), ("acmm", 0.1)])
def test_window_choice_matches_reference(weighting: str, ratio: float) -> None:
    """Per-pixel window: the fine window exactly where its variance tests pass (the ratio test only at crease
    codes: the lower half), its weights in the first ns[1] entries (zeros after, summing to 1), moments equal
    to the fine window's own; the standard window elsewhere; fine_window=0 gives the standard window
    everywhere."""
    rng = np.random.default_rng(12)
    a, b = _cameras()
    img = _checker_texture(_mixed_texture(_smooth_noise(rng, 20, 24)))
    opts = PatchMatchOptions(ncc_weighting=weighting, fine_window=5, fine_crease_min_var_ratio=ratio)
    codes = np.full((20, 24), FINE_EDGE, np.uint8)
    codes[10:] = FINE_CREASE
    ctx = build_context(img, a, [img], [b], opts, fine_allowed=codes)
    n_std, n_fine = len(opts.window_offsets()) ** 2, len(opts.fine_window_offsets()) ** 2
    wgt = ctx.window_weights()[0]
    assert ctx.ns.tolist() == [n_std, n_fine] and wgt.shape[2] == max(n_std, n_fine)
    fine_offs = window_offsets_2d(opts.fine_window_offsets())
    sigma_c = opts.sigma_color if weighting == "colmap" else opts.acmm_sigma_color
    fine_c = opts.fine_sigma_color if weighting == "colmap" else sigma_c
    n_fine_px = 0
    for y in range(20):
        for x in range(24):
            offsets, sigma_s, sc = ref.window_choice_ref(img.astype(np.float64), x, y, opts, int(codes[y, x]))
            fine = len(offsets) == n_fine
            assert sc == (fine_c if fine else sigma_c)
            wts, vals = ref.bilateral_weights_ref(img, x, y, fine_offs, weighting, opts.fine_sigma_spatial, sigma_c)
            var_test = (wts * vals * vals).sum() - (wts * vals).sum() ** 2
            if abs(var_test - opts.fine_min_var) < 1e-6:
                continue  # float32 kernel vs float64 reference may round either way at the thresholds
            if ratio > 0 and codes[y, x] == FINE_CREASE and var_test >= opts.fine_min_var:
                v_own = _variance(*ref.bilateral_weights_ref(img, x, y, fine_offs, weighting, opts.fine_sigma_spatial,
                                                             fine_c))
                std_offs = window_offsets_2d(opts.window_offsets())
                v_std = _variance(*ref.bilateral_weights_ref(img, x, y, std_offs, weighting, opts.sigma_spatial,
                                                             sigma_c))
                if abs(v_own - ratio * v_std) < 1e-6:
                    continue
            assert ctx.wset[y, x] == fine, (x, y)
            n_fine_px += fine
            ox, oy = ctx.offsets_at(x, y)
            np.testing.assert_array_equal(np.stack([ox, oy], 1), offsets)
            wts, vals = ref.bilateral_weights_ref(img, x, y, offsets, weighting, sigma_s, sc)
            np.testing.assert_allclose(wgt[y, x, : len(offsets)], wts, rtol=1e-4, atol=1e-7)
            assert np.all(wgt[y, x, len(offsets):] == 0)
            assert ctx.mu_a[y, x] == pytest.approx((wts * vals).sum(), abs=1e-5)
    assert 0.2 < n_fine_px / 480 < 0.7
    off = build_context(img, a, [img], [b], PatchMatchOptions(ncc_weighting=weighting, fine_window=0))
    assert not off.wset.any() and off.ns.tolist() == [n_std]
    std_offs = window_offsets_2d(opts.window_offsets())
    std_wgt = bilateral_moments(img, std_offs, weighting, opts.sigma_spatial, sigma_c)[0]
    np.testing.assert_array_equal(off.window_weights()[0], std_wgt)


def _variance(wts: np.ndarray, vals: np.ndarray) -> float:
    return float((wts * vals * vals).sum() - (wts * vals).sum() ** 2)


def test_crease_var_ratio_keeps_the_large_window_on_checkers() -> None:
    """In a crease band, fine_crease_min_var_ratio refuses the sharp-colour fine window on a two-tone checker
    (its weights keep only the centre's tone, leaving a flat window) but keeps it on most of a continuous
    texture; in an occlusion band (code FINE_EDGE) the ratio does not apply."""
    rng = np.random.default_rng(3)
    a, b = _cameras(48, 40)
    img = _checker_texture(_smooth_noise(rng, 40, 48))
    third = 2 * 48 // 3
    opts = PatchMatchOptions(fine_window=5, fine_crease_min_var_ratio=0.1)
    crease = np.full((40, 48), FINE_CREASE, np.uint8)
    off = build_context(img, a, [img], [b], opts.replace(fine_crease_min_var_ratio=0.0), fine_allowed=crease)
    on = build_context(img, a, [img], [b], opts, fine_allowed=crease)
    off, on = off.wset.astype(bool), on.wset.astype(bool)
    assert off[:, third:].mean() > 0.4  # the variance test alone passes wherever a checker edge is near
    assert on[:, third:].mean() < 0.1  # measured 0.85 -> 0.0
    assert on[:, : third - 3].mean() > 0.6 * off[:, : third - 3].mean()  # measured 1.0 -> 0.73
    assert not (on & ~off).any()  # the ratio only removes fine pixels
    edge = build_context(img, a, [img], [b], opts, fine_allowed=crease // 2).wset  # all FINE_EDGE
    np.testing.assert_array_equal(edge.astype(bool), off)


def _planes_map(cam: Camera, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Depth (H, W) and camera-frame normals (H, W, 3) of a slanted background plane with a nearer
    fronto-parallel box in front of it, a few holes, and normals jittered by about 1 degree."""
    h, w = cam.height, cam.width
    rays = cam.pixel_rays()
    n_bg = np.array([0.0, -0.6, -0.8])
    depth = 4.0 / -(rays @ n_bg)  # plane n·X = -4
    normal = np.broadcast_to(n_bg, (h, w, 3)).copy()
    box = (slice(6, 14), slice(8, 16))
    depth[box] = 2.5
    normal[box] = (0.0, 0.0, -1.0)
    depth[rng.random((h, w)) < 0.02] = 0.0
    normal += rng.normal(0, 0.02, normal.shape)
    normal /= np.linalg.norm(normal, axis=2, keepdims=True)
    return depth.astype(np.float32), normal.astype(np.float32)


@pytest.mark.parametrize("radius,crease_angle", [(0, 0.0), (2, 0.0), (0, 3.0), (2, 3.5)])
def test_depth_edge_band_matches_reference(radius: int, crease_angle: float) -> None:
    rng = np.random.default_rng(5)
    a, _ = _cameras()
    depth, normal = _planes_map(a, rng)  # normals jittered by ~1 degree: pairs on both sides of the angles
    noisy = depth * (1 + rng.normal(0, 0.01, depth.shape)).astype(np.float32)  # pairs on both sides of jump
    for d in (depth, noisy):
        got = depth_edge_band(d, normal, a.pixel_rays(), 0.02, radius, crease_angle)
        np.testing.assert_array_equal(got, ref.edge_band_ref(d, normal, a.K_idx, 0.02, radius, crease_angle))


def _crease_map(cam: Camera, half_angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Depth (H, W) and camera-frame normals of a room corner: two walls meeting in a vertical line through
    (0, 0, 5), each turned by ``half_angle_deg`` from fronto-parallel; the depth is continuous across it."""
    rays = cam.pixel_rays().astype(np.float64)
    phi = math.radians(half_angle_deg)
    x0 = np.array([0.0, 0.0, 5.0])
    depths, normals = [], []
    for n in (np.array([math.sin(phi), 0.0, -math.cos(phi)]), np.array([-math.sin(phi), 0.0, -math.cos(phi)])):
        t = (n @ x0) / (rays @ n)
        depths.append(np.where(t > 0, t * rays[..., 2], np.inf))
        normals.append(np.broadcast_to(n, rays.shape))
    nearer = depths[0] <= depths[1]
    depth = np.where(nearer, depths[0], depths[1])
    normal = np.where(nearer[..., None], normals[0], normals[1])
    return depth.astype(np.float32), normal.astype(np.float32)


def test_depth_edge_band_finds_creases_beyond_the_angle() -> None:
    """A room corner has no depth discontinuity; with ``crease_angle`` below the angle between its walls
    (40 degrees) the seam is an edge and nothing else is, above it nothing is."""
    a, _ = _cameras()
    depth, normal = _crease_map(a, 20.0)
    rays = a.pixel_rays()
    seam = np.zeros(depth.shape, bool)
    left = normal[..., 0] > 0
    seam[:, :-1] |= left[:, :-1] != left[:, 1:]
    seam[:, 1:] |= left[:, :-1] != left[:, 1:]
    assert 0 < left[0].sum() < depth.shape[1] and seam.sum() == 2 * depth.shape[0]  # one seam, mid-image
    assert not depth_edge_band(depth, normal, rays, 0.02, 0).any()
    np.testing.assert_array_equal(depth_edge_band(depth, normal, rays, 0.02, 0, 30.0), seam)
    assert not depth_edge_band(depth, normal, rays, 0.02, 0, 45.0).any()
    band = depth_edge_band(depth, normal, rays, 0.02, 2, 30.0)
    assert band.sum() == 6 * depth.shape[0]  # the two seam columns widened by 2 on each side
    opts = PatchMatchOptions(fine_window=5, fine_edge_radius=2, fine_crease_angle=30.0)
    np.testing.assert_array_equal(fine_window_region(depth, normal, a, opts), band * FINE_CREASE)
    assert not fine_window_region(depth, normal, a, opts.replace(fine_crease_angle=0.0)).any()
    depth[:, :3] = 0.0  # a hole at the left border: its band is an occlusion band (FINE_EDGE), the seam's not
    region = fine_window_region(depth, normal, a, opts)
    hole_band = depth_edge_band(depth, normal, rays, 0.02, 2)
    assert hole_band[:, :5].all() and not hole_band[band].any()
    np.testing.assert_array_equal(region, np.where(hole_band, FINE_EDGE, band * FINE_CREASE))


def test_depth_edge_band_finds_occlusions_not_slants() -> None:
    """The steep background plane (depth changing ~2-3 % per pixel along columns) has no edges; the box
    outline and the holes have, and the band widens them by the radius."""
    a, _ = _cameras()
    depth, normal = _planes_map(a, np.random.default_rng(5))
    rays = a.pixel_rays()
    step = np.abs(np.diff(depth, axis=0)) / np.maximum(depth[1:], 1e-6)
    assert np.median(step[depth[1:] * depth[:-1] > 0]) > 0.02  # a plain depth-ratio test would flag it
    edge = depth_edge_band(depth, normal, rays, 0.02, 0)
    holes = depth <= 0
    near_hole = np.zeros_like(holes)
    for dy, dx in ((0, 0), (0, 1), (0, -1), (1, 0), (-1, 0)):
        near_hole |= np.roll(holes, (dy, dx), axis=(0, 1))
    outline = np.zeros_like(holes)
    outline[5:15, 7:17] = True
    outline[7:13, 9:15] = False
    assert not (edge & ~near_hole & ~outline).any()  # nothing on the planes themselves
    assert (edge[outline & ~near_hole]).mean() > 0.4  # the box boundary is found
    band = depth_edge_band(depth, normal, rays, 0.02, 2)
    assert band[edge].all() and band.sum() > 2 * edge.sum()
    opts = PatchMatchOptions(fine_window=5, fine_edge_radius=2)
    np.testing.assert_array_equal(fine_window_region(depth, normal, a, opts), band)
    assert not fine_window_region(depth, normal, a, opts, random_start=True).any()
    assert not fine_window_region(depth, normal, a, opts, level=1).any()  # fine_max_level 0
    assert fine_window_region(depth, normal, a, opts.replace(fine_max_level=1), level=1).sum() == band.sum()
    assert fine_window_region(depth, normal, a, PatchMatchOptions(fine_edge_radius=0)) is None  # everywhere
    assert fine_window_region(depth, normal, a, PatchMatchOptions(fine_window=0), level=3) is None


def test_window_choice_respects_the_allowed_region() -> None:
    """With a fine-window region, exactly the pixels inside it that pass the variance test take the fine
    window, with the same weights as without the region."""
    rng = np.random.default_rng(12)
    a, b = _cameras()
    img = _mixed_texture(_smooth_noise(rng, 20, 24))
    opts = PatchMatchOptions(fine_window=5)
    allowed = np.zeros((20, 24), bool)
    allowed[4:16, 6:20] = True
    free = build_context(img, a, [img], [b], opts)
    ctx = build_context(img, a, [img], [b], opts, fine_allowed=allowed)
    np.testing.assert_array_equal(ctx.wset, free.wset * allowed)
    assert ctx.wset.any() and (free.wset & ~allowed).any()
    std = build_context(img, a, [img], [b], PatchMatchOptions(fine_window=0))
    wgt, free_wgt, std_wgt = ctx.window_weights()[0], free.window_weights()[0], std.window_weights()[0]
    for y in range(20):
        for x in range(24):
            offsets = ref.window_choice_ref(img.astype(np.float64), x, y, opts, int(allowed[y, x]))[0]
            assert len(offsets) == ctx.ns[ctx.wset[y, x]]
            src, src_wgt = (free, free_wgt) if ctx.wset[y, x] else (std, std_wgt)
            np.testing.assert_array_equal(wgt[y, x, : len(offsets)], src_wgt[y, x, : len(offsets)])
            assert ctx.mu_a[y, x] == src.mu_a[y, x]
    nowhere = build_context(img, a, [img], [b], opts, fine_allowed=np.zeros((20, 24), bool))
    assert nowhere.ns.tolist() == std.ns.tolist() and not nowhere.wset.any()  # e.g. a random-start pass
    np.testing.assert_array_equal(nowhere.window_weights()[0], std_wgt)


def test_reprojection_error_matches_reference() -> None:
    rng = np.random.default_rng(3)
    a, b = _cameras()
    depth_b = rng.uniform(3, 5, size=(20, 24)).astype(np.float32)
    depth_b[rng.random((20, 24)) < 0.2] = 0
    geo = relative_geometry(a, [b])
    from engine.patchmatch.geometry import reprojection_error

    for _ in range(100):
        x, y, z = int(rng.integers(0, 24)), int(rng.integers(0, 20)), float(rng.uniform(2.5, 6))
        got = reprojection_error(pack_geometry(geo, np.array([[24, 20]])), 0, depth_b[None], x, y, z)
        want = ref.reprojection_error_ref(a.K_idx, a.R, a.t, b.K_idx, b.R, b.t, depth_b, x, y, z)
        assert got == pytest.approx(want, abs=1e-6)


def test_plane_propagation_matches_reference_and_is_exact_on_a_plane() -> None:
    a, _ = _cameras()
    Ki = np.linalg.inv(a.K_idx)
    n = np.array([0.2, -0.1, -1.0])
    n /= np.linalg.norm(n)
    d = 4.0  # plane n·X + d = 0
    for q, p in [((3, 4), (3, 9)), ((10, 10), (17, 10)), ((5, 12), (5, 1))]:
        rq, rp = Ki @ [*q, 1.0], Ki @ [*p, 1.0]
        zq, zp = -d / (n @ rq), -d / (n @ rp)
        got = propagate_depth(zq, *n, tuple(rq), tuple(rp), True)
        assert got == pytest.approx(zp, rel=1e-9)
        assert got == pytest.approx(ref.propagate_depth_ref(a.K_idx, q, zq, n, p), rel=1e-12)
        assert propagate_depth(zq, *n, tuple(rq), tuple(rp), False) == zq


def test_random_normals_face_camera_and_match_reference() -> None:
    a, _ = _cameras()
    Ki = np.linalg.inv(a.K_idx)
    for i in range(50):
        key = np.uint64(combine(np.uint64(stream_key(7, 1, 0, 0, 0, 0)), i))
        rp = Ki @ [i % 24, i % 20, 1.0]
        nx, ny, nz, _ = random_normal(key, 3, tuple(rp))
        n = np.array([nx, ny, nz])
        assert np.linalg.norm(n) == pytest.approx(1.0, abs=1e-9)
        assert n @ rp < 0
        np.testing.assert_allclose(n, ref.random_normal_ref(int(key), 3, rp)[0], atol=1e-12)
        for eps in (1.0, 0.25, 0.01):
            px, py, pz, _ = perturb_normal(key, 50, tuple(rp), nx, ny, nz, eps, 3)
            m = np.array([px, py, pz])
            assert m @ rp < 0
            np.testing.assert_allclose(m, ref.perturb_normal_ref(int(key), 50, rp, n, eps, 3), atol=1e-9)
            if eps == 0.01:
                assert math.degrees(math.acos(min(1.0, float(m @ n)))) < 2.0


def test_rng_is_uniform_and_counter_based() -> None:
    key = stream_key(0, 0, 0, 0, 0, 0)
    u = np.array([uniform(key, i) for i in range(20000)])
    assert 0 <= u.min() and u.max() < 1
    assert abs(u.mean() - 0.5) < 0.01
    assert stream_key(0, 0, 0, 0, 0, 0) == key and stream_key(1, 0, 0, 0, 0, 0) != key


@pytest.mark.parametrize("name,count,regions", [("deepc", 24, 24), ("deepc_far", 24, 24), ("acmm", 72, 8)])
def test_sampling_patterns(name: str, count: int, regions: int) -> None:
    offs, region = sampling_pattern(name)
    assert offs.shape == (count, 2) and region.max() + 1 == regions
    assert np.all(np.abs(offs).sum(axis=1) % 2 == 1)  # always the other colour
    assert len({tuple(o) for o in offs}) == count


@pytest.mark.parametrize("deterministic", [True, False])
def test_view_weights_match_reference(deterministic: bool) -> None:
    rng = np.random.default_rng(4)
    for trial in range(60):
        n_views = int(rng.integers(1, 7))
        M = rng.uniform(0, 2, size=(8, n_views))
        n_rows = int(rng.integers(0, 9))
        Sel = rng.integers(0, 2**n_views, size=(3, 3)).astype(np.uint32)
        tau_g = 0.8 * math.exp(-(trial % 8) ** 2 / 90)
        omega, v = np.zeros(n_views), np.zeros(n_views)
        key = np.uint64(stream_key(trial, 0, 0, 0, 0, 0))
        total = view_weights(M, n_rows, n_views, Sel, 1, 1, tau_g, 1.2, 0.3, 0.4, 2, 3, 0.9, 0.1, deterministic, 15,
                             key, 0, omega, v)
        masks = [int(Sel[0, 1]), int(Sel[2, 1]), int(Sel[1, 0]), int(Sel[1, 2])]
        want = ref.view_weights_ref(M, n_rows, masks, tau_g, deterministic=deterministic, key=int(key))
        np.testing.assert_allclose(v, want, rtol=1e-12, atol=1e-12)
        assert total == pytest.approx(want.sum())


def test_jbu_matches_reference() -> None:
    rng = np.random.default_rng(5)
    depth_lo = rng.uniform(2, 4, size=(6, 7)).astype(np.float32)
    depth_lo[2, 3] = 0
    normal_lo = rng.normal(size=(6, 7, 3)).astype(np.float32)
    normal_lo[..., 2] = -np.abs(normal_lo[..., 2]) - 1
    guide = _smooth_noise(rng, 12, 14)
    got_d, got_n = jbu_upsample(depth_lo, normal_lo, guide, 2, 0.5, 0.1)
    want_d, want_n = ref.jbu_ref(depth_lo, normal_lo, guide, 2, 0.5, 0.1)
    np.testing.assert_allclose(got_d, want_d, rtol=1e-5)
    np.testing.assert_allclose(got_n, want_n, atol=1e-5)
    # constant input stays constant
    d, _ = jbu_upsample(np.full((6, 7), 3.0, np.float32), normal_lo, guide, 2, 0.5, 0.1)
    np.testing.assert_allclose(d, 3.0, rtol=1e-6)


def test_area_resize() -> None:
    rng = np.random.default_rng(6)
    img = rng.random((8, 10)).astype(np.float32)
    half = area_resize(img, 5, 4)
    np.testing.assert_allclose(half, img.reshape(4, 2, 5, 2).mean(axis=(1, 3)), rtol=1e-6)
    odd = area_resize(np.full((9, 11), 0.3, np.float32), 6, 5)
    np.testing.assert_allclose(odd, 0.3, rtol=1e-6)
    assert area_resize(img, 10, 8) is not None


def _tiny_problem(seed: int, geometric: bool, options: PatchMatchOptions, h: int = 14, w: int = 16):
    rng = np.random.default_rng(seed)
    a, b = _cameras(w, h)
    c = Camera.from_params(w, h, 20.0, 20.0, w / 2 + 0.3, h / 2 - 0.1, np.eye(3), np.array([0.35, -0.1, 0.0]))
    imgs = [_mixed_texture(_smooth_noise(rng, h, w)) for _ in range(3)]
    depths = [rng.uniform(2.5, 4.5, size=(h, w)).astype(np.float32) for _ in range(2)] if geometric else None
    ctx = build_context(imgs[0], a, imgs[1:], [b, c], options, depths)
    prob = ref.RefProblem(imgs[0], a, imgs[1:], [b, c], depths, options)
    st = ViewState.zeros(h, w)
    kinv = np.linalg.inv(a.K_idx).ravel()
    K.random_init_kernel(st.depth, st.normal, kinv, 2.0, 5.0, np.uint64(stream_key(seed, 0, 0, 0, 99, 0)), False)
    return ctx, prob, st


@pytest.mark.parametrize("geometric", [False, True])
def test_init_cost_matches_reference(geometric: bool) -> None:
    opts = PatchMatchOptions(init_top_k=2, fine_window=5 if geometric else 0)
    ctx, prob, st = _tiny_problem(8, geometric, opts)
    params = kernel_params(opts, 2.0, 5.0, 0, geometric, False, 24)
    init_cost(st, ctx, params)
    C_ref, S_ref = ref.init_cost_ref(prob, st.depth, st.normal, geometric)
    np.testing.assert_allclose(st.cost, C_ref, atol=5e-4)  # float32 NCC on the weak-texture third
    assert (st.selected_views == S_ref).mean() > 0.97  # masks may differ only on near-ties


def test_init_cost_reuses_the_previous_pass_costs_only_where_the_window_matches() -> None:
    """A geometric pass starts from the costs its photometric pass left (same images): the result is the same
    as evaluating every window again, a carried-over cost is used as it is (poisoned values show through), and
    a pixel whose window set changed, or a state without carried-over costs, is evaluated afresh."""
    opts = PatchMatchOptions(init_top_k=2, fine_window=5, fine_edge_radius=0)
    ctx, _, st = _tiny_problem(8, False, opts)
    params = kernel_params(opts, 2.0, 5.0, 0, False, False, 24)
    init_cost(st, ctx, params)
    fresh_C, fresh_P = st.cost.copy(), st.view_costs.copy()
    assert np.isfinite(fresh_P).mean() > 0.9
    # carried over from a pass that evaluated half of the views: same costs
    partial = fresh_P.astype(np.float32)
    partial[..., 0] = np.nan
    st.drop_caches(keep_costs_of=ctx)
    st.known_costs = partial.copy()
    init_cost(st, ctx, params)
    np.testing.assert_array_equal(st.cost, fresh_C)
    np.testing.assert_array_equal(st.view_costs, fresh_P)
    assert st.known_costs is None  # used once: the half-steps change the hypotheses
    # poisoned carried-over costs show where they are used
    poison = np.where(np.isfinite(fresh_P), np.float32(0.0), np.nan).astype(np.float32)
    changed_window = np.zeros(st.depth.shape, bool)
    changed_window[::3] = True
    st.known_costs, st.known_window_set = poison, np.where(changed_window, 1 - ctx.wset, ctx.wset).astype(np.uint8)
    init_cost(st, ctx, params)
    valid = np.isfinite(fresh_P).all(axis=-1)
    assert np.all(st.cost[valid & ~changed_window] == 0.0)
    np.testing.assert_array_equal(st.cost[changed_window], fresh_C[changed_window])


@pytest.mark.parametrize("geometric,pattern,view_sampling,combos,detail,eps,alpha,min_improvement", [
    (False, "deepc", "monte_carlo", "acmm5", False, None, 0.0, 0.0),
    (True, "acmm", "deterministic", "all8", False, None, 0.0, 0.0),
    (False, "deepc_far", "deterministic", "acmm5", False, 2.0**-6, 2.0, 0.0),  # decaying tau_g: 0.49 at t = 1
    (False, "deepc", "monte_carlo", "acmm5", True, 2.0**-7, 0.0, 0.003),
    (True, "deepc", "monte_carlo", "acmm5", False, None, 0.0, 0.05),
])
def test_half_step_matches_reference(geometric: bool, pattern: str, view_sampling: str, combos: str, detail: bool,
                                     eps: float | None, alpha: float, min_improvement: float) -> None:
    opts = PatchMatchOptions(pattern=pattern, view_sampling=view_sampling, combos=combos, k_update=10, k_viewsel=6,
                             fine_window=0 if pattern == "deepc_far" else 5, alpha=alpha,
                             min_improvement=min_improvement)
    ctx, prob, st = _tiny_problem(9, geometric, opts)
    pat = pattern_of(opts)
    params = kernel_params(opts, 2.0, 5.0, 1, geometric, detail, n_regions(pat), eps)
    init_cost(st, ctx, params)
    Z, N, C, S = st.depth.copy(), st.normal.copy(), st.cost.copy(), st.selected_views.copy()
    Z0 = st.depth.copy()
    # detail restorer: a reference cost that lets about half of the pixels through
    alternate = (np.arange(st.cost.size).reshape(st.cost.shape) % 2) * np.float32(0.5)
    cpre = st.cost + np.float32(0.1) + alternate if detail else st.cost.copy()
    key = np.uint64(stream_key(3, 0, 0, 0, 1, 0))
    half_step(st, ctx, 0, cpre.astype(np.float32), pat, key, params)
    ref.half_step_ref(prob, Z, N, C, S, cpre.astype(np.float32), 0, int(key), 1, 2.0, 5.0, geometric, detail,
                      tuple(pat), eps)
    same = np.isclose(st.depth, Z, rtol=1e-5) & np.all(np.isclose(st.normal, N, atol=1e-5), axis=-1)
    assert same.mean() > 0.97, f"{(~same).sum()} of {same.size} pixels differ"
    both = same & np.isclose(st.cost, C, atol=1e-3)
    assert both.mean() > 0.95
    assert (st.depth != Z0).any()  # the step did change something


class FixedBlocks:
    """A row pacer (``engine.core.blocks.RowPacer``'s ``run``) with fixed block boundaries; ``only``: the index of
    the one block it runs (the others are left alone), None for all."""

    def __init__(self, *cuts: int, only: int | None = None):
        self.cuts, self.only = cuts, only

    def run(self, kind: str, height: int, width: int, call) -> None:  # noqa: ARG002
        edges = [0, *[c for c in self.cuts if 0 < c < height], height]
        for i, (a, b) in enumerate(zip(edges, edges[1:], strict=False)):
            if self.only is None or i == self.only:
                call(a, b)


def test_a_diamond_updates_its_pixels_as_the_whole_view_does_and_leaves_the_others() -> None:
    """The initial cost and a half-step with ``KernelParams.box_r`` (the probe's dependency cone of one pixel):
    inside the diamond the same maps as a whole-view call (a pixel's update reads only the start state), outside
    it nothing written."""
    opts = PatchMatchOptions(k_update=10, k_viewsel=6, fine_window=5, init_top_k=2)
    ctx, _, st = _tiny_problem(9, False, opts)
    pat = pattern_of(opts)
    h, w = st.depth.shape
    cx, cy, r = w // 2, h // 2, 5
    ys, xs = np.mgrid[:h, :w]
    inside = (np.abs(xs - cx) + np.abs(ys - cy) <= r) & (xs >= cx - 4)  # the box cuts the diamond's left tip
    whole = kernel_params(opts, 2.0, 5.0, 1, False, False, n_regions(pat))
    part = kernel_params(opts, 2.0, 5.0, 1, False, False, n_regions(pat), box=(cx - 4, 0, w, h, cx, cy, r))
    start = (st.depth.copy(), st.normal.copy())
    init_cost(st, ctx, whole)
    whole_cost = st.cost.copy()
    st.cost[:] = -1.0
    init_cost(st, ctx, part)
    assert np.array_equal(st.cost[inside], whole_cost[inside]) and np.all(st.cost[~inside] == -1.0)
    st.cost[:] = whole_cost
    key = np.uint64(stream_key(3, 0, 0, 0, 1, 0))
    half_step(st, ctx, 0, whole_cost.copy(), pat, key, whole)
    after = st.depth.copy()
    st.depth[:], st.normal[:] = start
    init_cost(st, ctx, whole)
    counts = half_step(st, ctx, 0, whole_cost.copy(), pat, key, part)
    red = (xs + ys) % 2 == 0
    assert np.array_equal(st.depth[inside], after[inside])
    assert np.array_equal(st.depth[~inside], start[0][~inside])
    assert counts[K.CNT_PIXELS] == (inside & red).sum()


@pytest.mark.parametrize("geometric", [False, True])
def test_a_block_of_rows_matches_the_reference_and_leaves_the_other_rows(geometric: bool) -> None:
    """The initial cost and a half-step over one block of rows: the block as the reference computes those rows,
    every other row untouched."""
    opts = PatchMatchOptions(k_update=10, k_viewsel=6, fine_window=5, init_top_k=2)
    ctx, prob, st = _tiny_problem(9, geometric, opts)
    pat = pattern_of(opts)
    params = kernel_params(opts, 2.0, 5.0, 1, geometric, False, n_regions(pat))
    rows = (3, 9)
    init_cost(st, ctx, params)
    full_C = st.cost.copy()
    st.cost[:] = -1.0
    init_cost(st, ctx, params, pacer=FixedBlocks(*rows, only=1))
    C_ref, _ = ref.init_cost_ref(prob, st.depth, st.normal, geometric, rows)
    np.testing.assert_allclose(st.cost[3:9], C_ref[3:9], atol=5e-4)
    assert np.array_equal(st.cost[3:9], full_C[3:9]) and np.all(st.cost[:3] == -1.0) and np.all(st.cost[9:] == -1.0)
    st.cost[:] = full_C
    Z, N, C, S = st.depth.copy(), st.normal.copy(), st.cost.copy(), st.selected_views.copy()
    key = np.uint64(stream_key(3, 0, 0, 0, 1, 0))
    counts = half_step(st, ctx, 0, st.cost.copy(), pat, key, params, pacer=FixedBlocks(*rows, only=1))
    ref.half_step_ref(prob, Z, N, C, S, st.cost.copy(), 0, int(key), 1, 2.0, 5.0, geometric, False, tuple(pat),
                      rows=rows)
    outside = np.ones(st.depth.shape, bool)
    outside[3:9] = False
    assert np.array_equal(st.depth[outside], Z[outside]) and np.array_equal(st.cost[outside], C[outside])
    same = np.isclose(st.depth, Z, rtol=1e-5) & np.all(np.isclose(st.normal, N, atol=1e-5), axis=-1)
    assert same.mean() > 0.97, f"{(~same).sum()} of {same.size} pixels differ"
    assert counts[K.CNT_PIXELS] == (9 - 3) * st.depth.shape[1] // 2


@pytest.mark.parametrize("geometric,active", [(False, True), (True, False)])
def test_row_blocks_do_not_change_a_pass(geometric: bool, active: bool) -> None:
    """Initial cost and half-steps run as one call per view and as uneven row blocks give the same maps, cost
    caches, stamps and counts, bit for bit (a pixel reads only the other colour, which no block of its half-step
    writes)."""
    opts = PatchMatchOptions(active_share=0.1 if active else -1.0)
    ctx, _, start = _tiny_problem(12, geometric, opts, 48, 64)
    pattern = pattern_of(opts)
    changed = (np.random.default_rng(2).random(start.depth.shape) < 0.003).astype(np.uint8)
    results = []
    for pacer in (None, FixedBlocks(1, 2, 7, 30, 31, 47), FixedBlocks(24)):
        st = start.copy_maps()
        params = kernel_params(opts, 2.0, 5.0, 0, geometric, False, n_regions(pattern))
        init_cost(st, ctx, params, pacer=pacer)
        st.changed[:] = changed  # a converging pass: few pixels moved (what the active set skips)
        counts = []
        for t in range(2, 6):
            params = kernel_params(opts, 2.0, 5.0, t, geometric, False, n_regions(pattern), last=t == 5)
            for colour in (0, 1):
                key = np.uint64(stream_key(4, 0, 0, 0, t, colour))
                counts.append(half_step(st, ctx, colour, st.cost.copy(), pattern, key, params, pacer=pacer))
        kept = np.arange(st.row_samples.shape[2]) < st.row_count[..., None]  # the row slots in use (others: garbage)
        arrays = [*st.maps(), st.view_costs, st.versions, st.row_samples[kept], st.row_stamps, st.row_costs[kept],
                  st.row_count, st.changed, st.clock]
        results.append(([a.tobytes() for a in arrays], np.array(counts)))
    for arrays, counts in results[1:]:
        assert arrays == results[0][0]
        assert np.array_equal(counts, results[0][1])
    assert results[0][1][:, K.CNT_SKIPPED].any() == active  # the active set was exercised


@pytest.mark.parametrize("all8", [False, True])
def test_refinement_hypotheses_match_reference(all8: bool) -> None:
    rng = np.random.default_rng(6)
    kinv = np.linalg.inv(_cameras()[0].K_idx).ravel()
    hz, hn = np.empty(8), np.empty((8, 3))
    for _ in range(40):
        key = np.uint64(rng.integers(1 << 62))
        x, y = int(rng.integers(0, 24)), int(rng.integers(0, 20))
        rp = ray(kinv, x, y)
        z = float(rng.uniform(2.0, 5.0))
        nb = np.asarray(random_normal(np.uint64(rng.integers(1 << 62)), 0, rp)[:3])
        eps = float(2.0 ** -rng.integers(0, 8))
        n_h = K.refinement_hypotheses(key, rp, z, nb[0], nb[1], nb[2], 2.0, 5.0, eps, 3, all8, hz, hn)
        want = ref.refinement_hypotheses_ref(int(key), np.asarray(rp), z, nb, 2.0, 5.0, eps, 3, all8)
        assert n_h == len(want) == (8 if all8 else 5)
        for i, (zz, nn) in enumerate(want):
            assert hz[i] == pytest.approx(zz, rel=1e-12)
            np.testing.assert_allclose(hn[i], nn, atol=1e-9)


def test_cached_rows_reuse_a_row_only_for_the_same_sample_of_an_unchanged_pixel() -> None:
    pat = pattern_of(PatchMatchOptions()).offsets
    h, w, k_up, n_views = 30, 30, 4, 3
    x, y = 15, 15
    VER = np.zeros((h, w), np.uint32)
    RS = np.zeros((h, w, k_up), np.int8)
    RT = np.zeros((h, w), np.uint32)
    RC = np.arange(h * w * k_up * n_views, dtype=np.float32).reshape(h, w, k_up, n_views)
    RS[y, x, :3] = [5, 9, 2]  # the previous update's samples, written in half-step 4
    RT[y, x] = 4
    # sample 9's pixel changed since (half-step 5), sample 5's before (half-step 3): only 9's row is stale
    VER[y + pat[9, 1], x + pat[9, 0]] = 5
    VER[y + pat[5, 1], x + pat[5, 0]] = 3
    cand_s = np.array([2, 5, 9, 7], np.int64)  # 2 and 5 in other slots, 9 stale, 7 new
    R = np.empty((k_up, n_views))
    K.cached_rows(R, cand_s, 4, 3, x, y, pat, VER, RS, RT, RC)
    np.testing.assert_array_equal(R[0], RC[y, x, 2])
    np.testing.assert_array_equal(R[1], RC[y, x, 0])
    assert np.isnan(R[2:]).all()
    RT[y, x] = 0  # no update wrote rows yet: nothing is known
    K.cached_rows(R, cand_s, 4, 3, x, y, pat, VER, RS, RT, RC)
    assert np.isnan(R).all()


def test_view_order_is_heaviest_first_over_positive_weights() -> None:
    rng = np.random.default_rng(5)
    for _ in range(50):
        v = rng.integers(0, 4, size=int(rng.integers(1, 12))).astype(np.float64)
        order = np.empty(v.size, np.int64)
        n = K.view_order(v, order)
        want = [int(j) for j in np.argsort(-v, kind="stable") if v[j] > 0]
        assert order[:n].tolist() == want


@pytest.mark.parametrize("geometric", [False, True])
def test_aggregated_cost_equals_the_plain_in_order_sum_bit_for_bit(geometric: bool) -> None:
    """Heaviest-view-first evaluation with early exit (in geometric passes first on the geometric terms
    and the costs already known), with no, some or all of the costs known from a cached row, and the
    current-hypothesis path give exactly the value of
    Σ_j v_j (m_j + λ g_j) summed in view order (BIG when that reaches the threshold), which is what
    every earlier engine computed: regression baselines depend on it."""
    opts = PatchMatchOptions(fine_window=5)
    ctx, prob, st = _tiny_problem(10, geometric, opts)
    rng = np.random.default_rng(11)
    n_src = ctx.num_sources
    lam, gmax, min_var = opts.geom_lambda, opts.geom_max, opts.min_var
    order, terms = np.empty(n_src, np.int64), np.empty(n_src, np.float64)
    exits = geometric_exits = 0
    for _ in range(150):
        x, y = int(rng.integers(0, 16)), int(rng.integers(0, 14))
        rp = ray(ctx.kinv, x, y)
        z = float(rng.uniform(2.0, 5.0))
        n = np.asarray(random_normal(np.uint64(rng.integers(1 << 62)), 0, rp)[:3])
        v = rng.integers(0, 6, size=n_src).astype(np.float64)
        if v.sum() == 0:
            v[0] = 1.0
        vsum = float(v.sum())
        from engine.patchmatch.geometry import plane_vector

        m0, m1, m2, ok = plane_vector(ctx.kinv, rp, z, *n)
        n_samples = ctx.window_at(x, y, WIN)
        row = np.array([K.photometric_cost(ctx.flat, ctx.stride, ctx.plane, ctx.geo, j, WIN, n_samples,
                                           ctx.mu_a[y, x], ctx.var_a[y, x], x, y, m0, m1, m2, min_var, SIDX)
                        for j in range(n_src)])
        acc = geom_only = 0.0
        for j in range(n_src):
            if v[j] > 0:
                cost = row[j]
                if geometric:
                    g = lam * K.geometric_cost(ctx.geo, ctx.sdepth, j, x, y, z, gmax)
                    cost += g
                    geom_only += v[j] * g
                acc += v[j] * cost
        threshold = float(rng.uniform(0.2, 1.5)) if rng.random() < 0.8 else acc / vsum  # also the exact tie
        want = K.BIG if acc >= threshold * vsum else acc / vsum
        exits += want == K.BIG
        geometric_exits += geom_only >= threshold * vsum  # rejected before any image window is sampled
        n_sel = K.view_order(v, order)
        # no cost known, all known (the row of an unchanged neighbour's candidate), some known
        for known_views in (np.zeros(n_src, bool), np.ones(n_src, bool), rng.random(n_src) < 0.5):
            rows = np.full((3, n_src), np.nan)  # the cost row is row 1 of a cache
            rows[1] = np.where(known_views, row, np.nan)
            given = rows[1]
            got = K.aggregated_cost(ctx.flat, ctx.stride, ctx.plane, ctx.geo, ctx.sdepth, ctx.kinv, WIN, n_samples,
                                    ctx.mu_a[y, x], ctx.var_a[y, x], x, y, rp, z, n[0], n[1], n[2], v, vsum, order,
                                    n_sel, terms, geometric, lam, gmax, min_var, threshold, rows, 1, SIDX)
            assert got == want
            assert np.isnan(rows[[0, 2]]).all()  # only its own row
            # what it evaluated was added to the row, exactly
            assert np.array_equal(given[~np.isnan(given)], row[~np.isnan(given)])
            if want != K.BIG:
                assert not np.isnan(given[v > 0]).any()
        P = np.full(ctx.mu_a.shape + (n_src,), np.nan)
        known = P[y, x]
        known[: n_src // 2] = row[: n_src // 2]
        assert K.current_cost(ctx.flat, ctx.stride, ctx.plane, ctx.geo, ctx.sdepth, ctx.kinv, WIN, n_samples,
                              ctx.mu_a[y, x], ctx.var_a[y, x], x, y, rp, z, n[0], n[1], n[2], v, vsum, geometric, lam,
                              gmax, min_var, P, SIDX) == acc / vsum
        assert np.array_equal(known[v > 0], row[v > 0])  # evaluated views were added to the cache
    assert 10 < exits < 140
    assert (geometric_exits > 5) == geometric, geometric_exits  # the geometric-only bound was exercised


@pytest.mark.parametrize("geometric,combos", [(False, "acmm5"), (True, "all8")])
def test_cost_caches_do_not_change_half_steps(geometric: bool, combos: str) -> None:
    """Half-steps with the per-pass cost caches live give bit-identical maps to half-steps that start
    every update from empty caches (i.e. evaluate every cost afresh), with far fewer NCC windows."""
    opts = PatchMatchOptions(combos=combos)
    ctx, _, st = _tiny_problem(12, geometric, opts)
    pattern = pattern_of(opts)
    params = kernel_params(opts, 2.0, 5.0, 0, geometric, False, n_regions(pattern))
    init_cost(st, ctx, params)
    fresh = st.copy_maps()
    hits = 0
    n_cached = np.zeros(K.N_COUNTS, np.int64)
    n_fresh = np.zeros(K.N_COUNTS, np.int64)
    for t in range(4):
        params = kernel_params(opts, 2.0, 5.0, t, geometric, False, n_regions(pattern))
        for colour in (0, 1):
            key = np.uint64(stream_key(4, 0, 0, 0, t, colour))
            if t > 0:
                hits += int(np.sum(st.row_count > 0))
            n_cached += half_step(st, ctx, colour, st.cost.copy(), pattern, key, params)
            fresh.drop_caches()
            n_fresh += half_step(fresh, ctx, colour, fresh.cost.copy(), pattern, key, params)
            for a, b in zip(st.maps(), fresh.maps(), strict=True):
                assert a.tobytes() == b.tobytes()
    assert hits > 0
    assert n_cached[K.CNT_PIXELS] == n_fresh[K.CNT_PIXELS] == 4 * st.depth.size
    # every pixel update: the view-selection rows cost at most K_vs windows per source view afresh, and
    # the refinement (never cached) the same with and without caches
    assert 0 < n_fresh[K.CNT_ROWS] <= opts.k_viewsel * ctx.num_sources * n_fresh[K.CNT_PIXELS]
    assert n_cached[K.CNT_REFINE] == n_fresh[K.CNT_REFINE] > 0
    assert n_cached[K.CNT_ROWS] < 0.9 * n_fresh[K.CNT_ROWS]
    assert n_cached[K.CNT_REMAINING] < n_fresh[K.CNT_REMAINING]
    assert n_cached[K.CNT_CURRENT] < n_fresh[K.CNT_CURRENT]
    # slots the next update would hit: the sample's pixel last changed before the half-step that made the row
    h, w = st.depth.shape
    live = 0
    for y in range(h):
        for x in range(w):
            for k in range(st.row_count[y, x]):
                dx, dy = pattern.offsets[st.row_samples[y, x, k]]
                live += st.versions[y + dy, x + dx] < st.row_stamps[y, x]
    assert live > 0.2 * st.row_count.sum(), (live, st.row_count.sum())
    # the cached per-view costs of the stored hypotheses are their true costs
    known = ~np.isnan(st.view_costs)
    assert known.mean() > 0.1
    check = st.copy_maps()
    init_cost(check, ctx, params)
    assert np.array_equal(st.view_costs[known], check.view_costs[known])


def test_min_improvement_keeps_hypotheses_that_are_not_clearly_beaten() -> None:
    """A replacement must be cheaper by more than ``min_improvement``: the larger the margin, the fewer pixels
    change; a margin no cost difference can reach changes no hypothesis."""
    changed = []
    for margin in (0.0, 0.003, 0.05, 10.0):
        opts = PatchMatchOptions(min_improvement=margin)
        ctx, _, st = _tiny_problem(12, False, opts)
        run_view_level(st, ctx, opts, 2.0, 5.0, iterations=3)  # past the random start, where almost any
        # candidate wins by far; then one more iteration that is not a pass's last (where any lower cost wins)
        params = kernel_params(opts, 2.0, 5.0, 3, False, False, n_regions(pattern_of(opts)))
        init_cost(st, ctx, params)
        Z, N = st.depth.copy(), st.normal.copy()
        for colour in (0, 1):
            half_step(st, ctx, colour, st.cost.copy(), pattern_of(opts), np.uint64(stream_key(4, 0, 0, 0, 3, colour)),
                      params)
        moved = (st.depth != Z) | np.any(st.normal != N, axis=-1)
        changed.append(moved.mean())
        if margin == 10.0:
            assert not moved.any()  # (C is still recomputed: the view weights change from update to update)
    assert changed[0] > changed[1] > changed[2] > changed[3] == 0.0, changed


def test_run_view_level_runs_a_pass_and_reports_every_iteration() -> None:
    """The public one-view entry point: initial cost, then the iterations (each reported with the windows it
    evaluated and every pixel updated once), and the caches dropped at the end, the final hypotheses' costs
    kept for the level's next pass only."""
    opts = PatchMatchOptions(geom_passes=1)
    ctx, _, st = _tiny_problem(12, False, opts)
    start = st.copy_maps()
    seen = []
    total = run_view_level(st, ctx, opts, 2.0, 5.0, iterations=3,
                           on_iteration=lambda t, counts, seconds: seen.append((t, counts.copy(), seconds)))
    assert [t for t, _, _ in seen] == [0, 1, 2]
    assert all(c[K.CNT_PIXELS] == st.depth.size and c[: K.CNT_PIXELS].sum() > 0 and s >= 0 for _, c, s in seen)
    np.testing.assert_array_equal(total, sum(c for _, c, _ in seen))
    assert (st.depth != start.depth).mean() > 0.5
    assert st.view_costs is None and st.row_count is None
    assert st.known_costs is None  # not carried to the next pass: its init_cost recomputes them (memory)
    again = start.copy_maps()
    run_view_level(again, ctx, opts, 2.0, 5.0, iterations=3)
    for a, b in zip(st.maps(), again.maps(), strict=True):
        assert a.tobytes() == b.tobytes()  # same streams, same maps
    run_view_level(again, ctx, opts, 2.0, 5.0, pass_index=1, iterations=1)  # the level's last pass
    assert again.known_costs is None


def test_a_converged_pass_ends_early_with_its_last_iteration() -> None:
    """With ``converge_ratio`` a pass stops once an iteration changes nearly as many pixels as the one before:
    fewer iterations than the schedule, the same first iterations as the full pass (same streams), and the
    stopping iteration run as the pass's last (any lower cost accepted). Off (0), the schedule's count runs."""
    full = PatchMatchOptions(schedule="paper", converge_ratio=0, active_share=-1)
    ctx, _, st = _tiny_problem(12, False, full)
    start = st.copy_maps()
    ran_full: list[int] = []
    run_view_level(st, ctx, full, 2.0, 5.0, on_iteration=lambda t, c, s: ran_full.append(t))
    assert ran_full == list(range(8))
    early = full.replace(converge_ratio=0.95)
    st_early = start.copy_maps()
    ran: list[int] = []
    run_view_level(st_early, ctx, early, 2.0, 5.0, on_iteration=lambda t, c, s: ran.append(t))
    assert 3 <= len(ran) < 8 and ran == list(range(len(ran)))
    # the same pass cut at the same iteration by the schedule gives the same maps
    cut = start.copy_maps()
    run_view_level(cut, ctx, full, 2.0, 5.0, iterations=len(ran))
    for a, b in zip(st_early.maps(), cut.maps(), strict=True):
        assert a.tobytes() == b.tobytes()


def test_convergence_counts_pixels_moved_beyond_the_tolerance() -> None:
    """The changed share is of pixels whose depth moved by more than converge_depth (relative); the pass has
    converged when that share stops falling by the ratio."""
    from engine.patchmatch.view_pass import Convergence

    depth = np.full((10, 10), 2.0, np.float32)
    conv = Convergence(depth, PatchMatchOptions(converge_ratio=0.8, converge_depth=0.01))
    moved = depth.copy()
    moved[:5] *= 1.05  # half the pixels move 5 %
    moved[5, 0] *= 1.001  # one moves less than the tolerance
    assert not conv.update(moved) and conv.changed == [0.5]
    moved = moved.copy()
    moved[:2] *= 1.05  # 20 % move: falling fast, not converged
    assert not conv.update(moved) and conv.changed[-1] == 0.2
    moved = moved.copy()
    moved[:1] *= 1.05  # 10 %: fell by half, more than 0.8 would allow -> not converged
    assert not conv.update(moved)
    moved = moved.copy()
    moved[:1] *= 1.05  # 10 % again: stopped falling -> converged
    assert conv.update(moved)


def _active_mask(changed: np.ndarray, pattern, colour: int, key: np.uint64, share: float) -> np.ndarray:
    """Pixels of ``colour`` the active set updates, written from the rule: the pixel, a pattern sample or a
    4-neighbour changed in its last update, or the pixel's draw 1 << 16 is below ``share``."""
    h, w = changed.shape
    reach = [tuple(int(v) for v in o) for o in pattern.offsets] + [(0, -1), (0, 1), (-1, 0), (1, 0)]
    mask = np.zeros((h, w), bool)
    for y in range(h):
        for x in range((y + colour) % 2, w, 2):
            moved = changed[y, x] or any(changed[y + dy, x + dx] for dx, dy in reach
                                         if 0 <= x + dx < w and 0 <= y + dy < h)
            mask[y, x] = moved or uniform(np.uint64(combine(key, y * w + x)), K.ACTIVE_DRAW) < share
    return mask


def test_active_set_updates_only_pixels_whose_neighbourhood_changed() -> None:
    """With share 0 and nothing changed, a half-step leaves every pixel alone (maps bit for bit, all counted as
    skipped); one changed pixel makes exactly the pixels that read it (pattern samples, 4-neighbours) active."""
    opts = PatchMatchOptions(active_share=0.0)
    ctx, _, st = _tiny_problem(12, False, opts)
    pattern = pattern_of(opts)
    params = kernel_params(opts, 2.0, 5.0, 2, False, False, n_regions(pattern))
    assert params.active_share == 0.0 and params.track_changes
    init_cost(st, ctx, params)
    key = np.uint64(stream_key(5, 0, 0, 0, 2, 0))
    st.changed[:] = 0
    before = st.copy_maps()
    counts = half_step(st, ctx, 0, st.cost.copy(), pattern, key, params)
    assert counts[K.CNT_SKIPPED] == st.depth.size // 2 and counts[K.CNT_PIXELS] == 0 and counts[:4].sum() == 0
    for a, b in zip(st.maps(), before.maps(), strict=True):
        assert a.tobytes() == b.tobytes()
    # pixel q = (7, 4) (colour 1) changed: the colour-0 pixels that read it are updated, no other
    st.changed[4, 7] = 1
    want = _active_mask(st.changed, pattern, 0, key, 0.0)
    assert want[4, 10] and want[4, 8] and not want[5, 9]  # a pattern sample 3 px away, a 4-neighbour; neither
    counts = half_step(st, ctx, 0, st.cost.copy(), pattern, key, params)
    assert counts[K.CNT_PIXELS] == want.sum() and counts[K.CNT_SKIPPED] == st.depth.size // 2 - want.sum()
    assert counts[:4].sum() > 0
    for a, b in zip(st.maps(), before.maps(), strict=True):
        assert a[~want].tobytes() == b[~want].tobytes()
    assert (st.cost[want] != before.cost[want]).any()  # updated: at least the cost under new view weights
    assert st.changed[~want & (np.indices(want.shape).sum(axis=0) % 2 == 0)].max() == 0


@pytest.mark.parametrize("geometric", [False, True])
def test_active_half_step_matches_reference(geometric: bool) -> None:
    """The active set of the kernel is the reference's (same pixels updated, with the share's random draws), and
    the updated pixels agree with the plain half-step as in :func:`test_half_step_matches_reference`."""
    opts = PatchMatchOptions(k_update=10, k_viewsel=6, active_share=0.25)
    ctx, prob, st = _tiny_problem(9, geometric, opts)
    pat = pattern_of(opts)
    params = kernel_params(opts, 2.0, 5.0, 3, geometric, False, n_regions(pat))
    init_cost(st, ctx, params)
    rng = np.random.default_rng(3)
    st.changed[:] = rng.random(st.depth.shape) < 0.01  # a few changed pixels: most of the image is quiet
    changed = st.changed.copy()
    Z, N, C, S = st.depth.copy(), st.normal.copy(), st.cost.copy(), st.selected_views.copy()
    key = np.uint64(stream_key(3, 0, 0, 0, 3, 1))
    want = _active_mask(changed, pat, 1, key, 0.25)
    assert 0.2 < want.sum() / (st.depth.size // 2) < 0.9
    counts = half_step(st, ctx, 1, st.cost.copy(), pat, key, params)
    ref.half_step_ref(prob, Z, N, C, S, st.cost.copy(), 1, int(key), 3, 2.0, 5.0, geometric, False, tuple(pat),
                      None, changed, 0.25)
    assert counts[K.CNT_PIXELS] == want.sum()
    assert np.array_equal(st.depth[~want], Z[~want]) and np.array_equal(st.cost[~want], C[~want])
    same = np.isclose(st.depth, Z, rtol=1e-5) & np.all(np.isclose(st.normal, N, atol=1e-5), axis=-1)
    assert same.mean() > 0.97
    assert (st.changed == changed).mean() > 0.97  # the change map agrees where the hypotheses do
    assert (st.changed[want] == 1).any()


def test_active_set_is_deterministic_whatever_the_thread_count() -> None:
    """Active half-steps from the same state and change map give bit-identical maps on 1 and 2 threads; in a
    pass, iterations before ACTIVE_FROM_ITERATION and the last one update every pixel, and every pixel is counted
    once per iteration."""
    import numba

    from engine.patchmatch.records import ACTIVE_FROM_ITERATION

    opts = PatchMatchOptions(active_share=0.1)
    ctx, _, start = _tiny_problem(12, False, opts, 48, 64)
    pattern = pattern_of(opts)
    seen: list[np.ndarray] = []
    run_view_level(start, ctx, opts, 2.0, 5.0, iterations=4, on_iteration=lambda t, c, s: seen.append(c.copy()))
    size = start.depth.size
    assert all(c[K.CNT_PIXELS] == size and c[K.CNT_SKIPPED] == 0 for c in seen[:ACTIVE_FROM_ITERATION] + seen[-1:])
    assert kernel_params(opts, 2.0, 5.0, 3, last=True).active_share < 0 < kernel_params(opts, 2.0, 5.0, 3).active_share
    assert all(c[K.CNT_PIXELS] + c[K.CNT_SKIPPED] == size for c in seen)
    changed = (np.random.default_rng(2).random(start.depth.shape) < 0.003).astype(np.uint8)
    maps: list[ViewState] = []
    skipped = 0
    threads = numba.get_num_threads()
    try:
        for n in (1, 2):
            numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
            st = start.copy_maps()
            params = kernel_params(opts, 2.0, 5.0, 4, False, False, n_regions(pattern))
            init_cost(st, ctx, params)
            st.changed[:] = changed
            for t in (4, 5):
                params = kernel_params(opts, 2.0, 5.0, t, False, False, n_regions(pattern))
                for colour in (0, 1):
                    key = np.uint64(stream_key(4, 0, 0, 0, t, colour))
                    skipped += half_step(st, ctx, colour, st.cost.copy(), pattern, key, params)[K.CNT_SKIPPED]
            maps.append(st)
    finally:
        numba.set_num_threads(threads)
    for a, b in zip(maps[0].maps(), maps[1].maps(), strict=True):
        assert a.tobytes() == b.tobytes()
    assert skipped > 0.2 * size


def test_window_terms_are_the_same_in_any_row_blocks_and_a_stop_request_ends_them_between_blocks() -> None:
    """The window moments and choices of a view built in one call and in blocks of rows are the same bit for bit;
    a stop request during a block (SIGTERM inside deferred_interrupts) ends the build when that block returns."""
    from test_refinement import StopAfterFirstBlock

    from engine.core.blocks import MIN_ROWS, RowPacer
    from engine.core.interrupt import deferred_interrupts
    from engine.patchmatch.ncc import window_terms

    rng = np.random.default_rng(3)
    img = _checker_texture(_mixed_texture(_smooth_noise(rng, 70, 40)))
    codes = np.full(img.shape, FINE_EDGE, np.uint8)
    codes[35:] = FINE_CREASE
    args = (img, window_offsets_2d(list(range(-5, 6, 2))), window_offsets_2d(list(range(-2, 3))), "colmap", 5.0,
            0.2, 1.5, 0.05, 1e-3, codes)
    whole = window_terms(*args, min_ratio_fine=0.1, pacer=None)
    assert whole[2].any() and not whole[2].all()  # both windows occur
    for pacer in (FixedBlocks(1, 2, 9, 29, 30), FixedBlocks(16), RowPacer(target_s=1e-6)):
        parts = window_terms(*args, min_ratio_fine=0.1, pacer=pacer)
        for a, b in zip(whole, parts, strict=True):
            assert a.tobytes() == b.tobytes()
        # the probe's partial replay asks for the pixels of its box only: those are the whole build's, bit for bit
        band = window_terms(*args, min_ratio_fine=0.1, pacer=pacer, box=(5, 31, 30, 52))
        inside = np.zeros(img.shape, bool)
        inside[31:52, 5:30] = True
        for a, b in zip(whole, band, strict=True):
            assert a[inside].tobytes() == b[inside].tobytes() and not b[~inside].any()
    stopper = StopAfterFirstBlock()
    with pytest.raises(KeyboardInterrupt), deferred_interrupts():
        window_terms(*args, min_ratio_fine=0.1, pacer=stopper)
    assert stopper.done == [(0, MIN_ROWS)]
