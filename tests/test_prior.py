"""The classical prior and the residual / fusion generator built on it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from leovr.depth.classical import nearest_fill
from leovr.depth.inference import predict, predict_at_focal, rescale_sparse, sampled_prior
from leovr.depth.network import DepthGenerator, GeneratorConfig
from leovr.depth import prior as prior_module
from leovr.depth.prior import delaunay_triangles, interpolated_fill, near_depth_edges, triangle_map


def ground_plane(h: int = 120, w: int = 200, f: float = 150.0, cam_height: float = 1.6) -> np.ndarray:
    """Depth of a flat road seen by a level pinhole camera (rows below the horizon only)."""
    v = np.arange(h, dtype=np.float64)[:, None] - h / 2 + 0.5
    depth = np.where(v > 0, f * cam_height / np.maximum(v, 1e-9), 0.0)
    return np.repeat(depth, w, axis=1).astype(np.float32)


def test_interpolation_is_exact_on_a_plane_where_nearest_fill_is_not():
    gt = ground_plane()
    sparse = np.zeros_like(gt)
    # rings every 4 rows (depth ratio < 1.25 ring to ring), a return every 2 columns
    sparse[80::4, ::2] = gt[80::4, ::2]
    inside = np.zeros_like(gt, bool)
    inside[80:117, 2:-2] = True  # between the first and the last ring
    prior, near = interpolated_fill(sparse), nearest_fill(sparse)
    err_prior = np.abs(prior - gt)[inside]
    err_near = np.abs(near - gt)[inside]
    assert err_prior.max() < 1e-3 * gt[inside].max()  # inverse depth is affine on a plane
    assert err_near.mean() > 20 * err_prior.mean()
    measured = sparse > 0
    np.testing.assert_array_equal(prior[measured], sparse[measured])
    assert (prior > 0).all()  # outside the hull: nearest return


def test_depth_edges_take_the_nearest_return_instead_of_a_blend():
    sparse = np.zeros((40, 60), np.float32)
    sparse[10::8, ::3] = 5.0  # a near wall on the left ...
    sparse[10::8, 30::3] = 20.0  # ... and the background on the right
    prior = interpolated_fill(sparse)
    assert set(np.unique(np.round(prior, 3))) == {5.0, 20.0}  # no flying pixel in between
    np.testing.assert_array_equal(prior, interpolated_fill(sparse, edge_ratio=1.5))
    assert len(np.unique(np.round(interpolated_fill(sparse, edge_ratio=np.inf), 3))) > 2  # blends without the test


def _two_layer_scene(boundary: int, h: int = 60, w: int = 80) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A near surface (5 m, red) above row `boundary`, background (20 m, blue) below; rings every 20 rows."""
    gt = np.where(np.arange(h)[:, None] < boundary, 5.0, 20.0).repeat(w, 1).astype(np.float32)
    img = np.zeros((h, w, 3), np.int64)
    img[:boundary], img[boundary:] = (200, 40, 40), (60, 60, 200)
    img = np.clip(img + np.random.default_rng(0).integers(-10, 10, img.shape), 0, 255).astype(np.uint8)
    sparse = np.zeros_like(gt)
    sparse[10::20, 1::2] = gt[10::20, 1::2]
    return gt, img, sparse


@pytest.mark.parametrize("boundary", [37, 43])
def test_the_image_picks_the_side_of_a_depth_edge_between_rings(boundary):
    gt, img, sparse = _two_layer_scene(boundary)
    gap = slice(31, 50)  # between the ring on the near surface (row 30) and the one on the background (row 50)
    err_image = np.abs(interpolated_fill(sparse, image=img) - gt)[gap].mean()
    err_nearest = np.abs(interpolated_fill(sparse) - gt)[gap].mean()  # splits the gap at its middle, row 40
    assert err_image < 0.8 * err_nearest
    if boundary == 43:
        assert err_image < 0.05  # the colour edge is the depth edge: (nearly) every pixel on its side
    # a float image in [0, 1] is the same image
    np.testing.assert_array_equal(interpolated_fill(sparse, image=img / 255.0), interpolated_fill(sparse, image=img))
    with pytest.raises(ValueError, match="image of 80x59 px"):
        interpolated_fill(sparse, image=img[:-1])


def test_the_image_side_holds_for_inputs_denser_than_the_interpolator_takes():
    """OpenCV's edge-aware interpolator asserts on 32767 matches or more; a denser input (a random
    30 % of a 448 x 256 map in training, a dense scan) guides with an evenly strided subset."""
    h, w, boundary = 256, 448, 131
    gt = np.where(np.arange(h)[:, None] < boundary, 5.0, 20.0).repeat(w, 1).astype(np.float32)
    img = np.zeros((h, w, 3), np.uint8)
    img[:boundary], img[boundary:] = (200, 40, 40), (60, 60, 200)
    sparse = np.zeros_like(gt)
    sparse[::2] = gt[::2]  # every second row: 57,344 returns
    sparse[120:140] = 0.0  # a gap around the depth edge
    sparse[128] = gt[128]  # one ring inside it
    gap = slice(129, 140)
    err_image = np.abs(interpolated_fill(sparse, image=img) - gt)[gap].mean()
    err_nearest = np.abs(interpolated_fill(sparse) - gt)[gap].mean()
    assert err_image < 0.5 * err_nearest


def test_a_dense_input_guides_with_the_returns_near_its_depth_edges(monkeypatch):
    """Above DENSE_RETURNS the image guide takes the returns near depth edges and a stride of the rest: the
    pixels at the edge come out as with every return."""
    h, w, boundary = 256, 448, 131
    gt = np.where(np.arange(h)[:, None] < boundary, 5.0, 20.0).repeat(w, 1).astype(np.float32)
    img = np.zeros((h, w, 3), np.uint8)
    img[:boundary], img[boundary:] = (200, 40, 40), (60, 60, 200)
    img = np.clip(img.astype(np.int64) + np.random.default_rng(1).integers(-10, 10, img.shape), 0, 255).astype(np.uint8)
    sparse = np.zeros_like(gt)
    sparse[::4, ::2] = gt[::4, ::2]  # 14,336 returns
    sparse[124:140] = 0.0  # a gap around the depth edge, one ring inside it
    sparse[128, ::2] = gt[128, ::2]
    assert (sparse > 0).sum() > prior_module.DENSE_RETURNS
    near = near_depth_edges(sparse)
    assert near[100:160].all()  # the rings on both sides of the edge and the gap between them
    assert not near[:80].any() and not near[180:].any()  # far from it
    selected = interpolated_fill(sparse, image=img)
    monkeypatch.setattr(prior_module, "DENSE_RETURNS", 10**9)
    every = interpolated_fill(sparse, image=img)
    gap = slice(129, 140)
    np.testing.assert_allclose(selected[gap], every[gap], rtol=1e-3)
    assert np.abs(selected - gt)[gap].mean() < 0.5 * np.abs(interpolated_fill(sparse) - gt)[gap].mean()


def test_a_steep_surface_between_far_rings_takes_the_image_guided_fit_not_a_corner(monkeypatch):
    """The road between rings whose depths differ by 2-2.3x: each triangle counts as a depth edge, but the
    edge-aware fit runs between its corners (no image edge), so the pixels take the fit's own depth."""
    from leovr.depth import prior

    gt = ground_plane()
    rows = [64, 70, 80, 100]  # 44, 19, 9.8 and 4.9 m: consecutive ratios 2.3, 2.0, 2.0
    sparse = np.zeros_like(gt)
    sparse[rows, 1::2] = gt[rows, 1::2]
    rng = np.random.default_rng(3)
    img = np.clip(120 + rng.normal(0, 6, gt.shape + (3,)), 0, 255).astype(np.uint8)  # road texture, no edge
    gap = slice(rows[0] + 1, rows[-1])
    fit = interpolated_fill(sparse, image=img)
    monkeypatch.setattr(prior, "EDGE_GUIDE_MAX_RATIO", 1.0)  # the corner rule alone
    corner = interpolated_fill(sparse, image=img)
    err_fit, err_corner = (np.abs(m - gt)[gap].mean() for m in (fit, corner))
    assert err_fit < 0.5 * err_corner
    assert len(np.unique(np.round(corner[gap], 3))) <= len(rows)  # corners only
    assert (fit[gap] < sparse[rows[0], 1] + 1e-3).all() and (fit[gap] > sparse[rows[-1], 1] - 1e-3).all()


def test_interpolation_degenerate_inputs():
    assert not interpolated_fill(np.zeros((10, 12), np.float32)).any()
    line = np.zeros((10, 12), np.float32)
    line[4, 2:9] = 5.0  # collinear returns: no triangle, nearest fill
    np.testing.assert_array_equal(interpolated_fill(line), nearest_fill(line))


@pytest.mark.parametrize("mode", ["residual", "fusion"])
def test_untrained_residual_generator_returns_its_prior(mode):
    torch.manual_seed(0)
    rng = np.random.default_rng(1)
    img = rng.integers(0, 255, (96, 160, 3), dtype=np.uint8)
    sparse = np.where(rng.random((96, 160)) < 0.05, rng.uniform(3, 60, (96, 160)), 0).astype(np.float32)
    model = DepthGenerator(GeneratorConfig(output=mode, channels=(8, 8, 16, 16, 16), blocks=(1, 1, 1, 1))).eval()
    depth, log_sigma = predict(model, img, sparse)  # the prior takes the side of depth edges from the image
    np.testing.assert_allclose(depth, interpolated_fill(sparse, image=img), rtol=1e-5)
    np.testing.assert_allclose(predict(model, img, sparse, image_edges=False)[0], interpolated_fill(sparse), rtol=1e-5)
    # run at another focal length: the residual is resized and the prior is built at full resolution
    full, _ = predict_at_focal(model, img, sparse, focal_px=300.0, model_focal_px=150.0)
    np.testing.assert_allclose(full, interpolated_fill(sparse, image=img), rtol=1e-5)
    assert depth.shape == log_sigma.shape == sparse.shape


def test_a_resampled_frame_reads_its_input_prior_from_the_full_resolution_prior():
    """The network's input prior on a frame run at another focal length is the full-resolution prior at the
    pixel each small pixel came from, with the small map's own returns kept; at scale 1 it is the prior."""
    rng = np.random.default_rng(3)
    img = rng.integers(0, 255, (90, 150, 3), dtype=np.uint8)
    gt = ground_plane(90, 150)
    sparse = np.where((rng.random(gt.shape) < 0.08) & (gt > 0), gt, 0).astype(np.float32)
    full = interpolated_fill(sparse, image=img)
    np.testing.assert_array_equal(sampled_prior(full, sparse, 1.0), full)
    small = rescale_sparse(sparse, 0.5, (45, 75))
    got = sampled_prior(full, small, 0.5)
    assert got.shape == (45, 75)
    measured = small > 0
    np.testing.assert_array_equal(got[measured], small[measured])
    r, c = np.nonzero(~measured)
    np.testing.assert_array_equal(got[r, c], full[np.minimum(2 * r, 89), np.minimum(2 * c, 149)])
    # and it is what the network reads: a recorder in place of the network sees the same map
    seen = {}

    class Recorder(DepthGenerator):
        def parts(self, image, sparse_in, prior):
            seen["prior"] = prior.clone()
            return super().parts(image, sparse_in, prior)

    model = Recorder(GeneratorConfig(output="residual", channels=(8, 8, 16, 16, 16), blocks=(1, 1, 1, 1))).eval()
    predict_at_focal(model, img, sparse, focal_px=300.0, model_focal_px=150.0)
    np.testing.assert_allclose(seen["prior"][0, 0, :45, :75].numpy(), got, rtol=1e-6)


def test_fusion_keeps_measured_pixels_close_to_the_measurement():
    """With a residual of +50 % everywhere, measured pixels move only by (1 - lambda(gamma)) of it."""
    model = DepthGenerator(GeneratorConfig(output="fusion", channels=(8, 8, 16, 16, 16), blocks=(1, 1, 1, 1))).eval()
    with torch.no_grad():
        model.depth_head.bias.fill_(float(np.log(1.5)))
        model.fusion_head.bias.fill_(3.0)  # far from the measurements the prior is distrusted
    rng = np.random.default_rng(2)
    img = rng.integers(0, 255, (64, 96, 3), dtype=np.uint8)
    sparse = np.where(rng.random((64, 96)) < 0.05, 10.0, 0).astype(np.float32)
    depth, _ = predict(model, img, sparse)
    lam_measured = 1.0 / (1.0 + np.exp(0.8 * -2.0))
    lam_far = 1.0 / (1.0 + np.exp(0.8 * 3.0))
    m = sparse > 0
    np.testing.assert_allclose(depth[m], 10.0 * (lam_measured + (1 - lam_measured) * 1.5), rtol=1e-4)
    np.testing.assert_allclose(depth[~m], 10.0 * (lam_far + (1 - lam_far) * 1.5), rtol=1e-4)


def _random_pixels(n: int, shape: tuple[int, int], seed: int) -> tuple[np.ndarray, np.ndarray]:
    flat = np.random.default_rng(seed).choice(shape[0] * shape[1], n, replace=False)
    return flat % shape[1], flat // shape[1]


@pytest.mark.parametrize("seed", [0, 1])
def test_delaunay_triangles_tile_the_hull_with_empty_circumcircles(seed):
    import cv2

    shape = (60, 90)
    u, v = _random_pixels(150, shape, seed)
    tri = delaunay_triangles(u, v, shape)
    p = np.stack([u, v], 1).astype(np.float64)
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    area = 0.5 * np.abs((b - a)[:, 0] * (c - a)[:, 1] - (c - a)[:, 0] * (b - a)[:, 1])
    hull = cv2.contourArea(cv2.convexHull(p.astype(np.float32)))
    assert area.sum() == pytest.approx(hull, rel=1e-9)  # the triangles tile the convex hull, none missing
    # Delaunay: no point lies strictly inside any triangle's circumcircle
    d = 2 * (a[:, 0] * (b[:, 1] - c[:, 1]) + b[:, 0] * (c[:, 1] - a[:, 1]) + c[:, 0] * (a[:, 1] - b[:, 1]))
    sq = [(q**2).sum(1) for q in (a, b, c)]
    centre = np.stack(
        [
            (sq[0] * (b[:, 1] - c[:, 1]) + sq[1] * (c[:, 1] - a[:, 1]) + sq[2] * (a[:, 1] - b[:, 1])) / d,
            (sq[0] * (c[:, 0] - b[:, 0]) + sq[1] * (a[:, 0] - c[:, 0]) + sq[2] * (b[:, 0] - a[:, 0])) / d,
        ],
        1,
    )
    radius = np.linalg.norm(a - centre, axis=1)
    dist = np.linalg.norm(p[None] - centre[:, None], axis=2)
    assert (dist >= radius[:, None] - 1e-6).all()
    assert len(delaunay_triangles(u[:2], v[:2], shape)) == 0


def test_triangle_map_covers_each_pixel_inside_or_on_a_triangle_and_nothing_else():
    shape = (60, 90)
    u, v = _random_pixels(80, shape, 2)
    corners = np.stack([u, v], 1)[delaunay_triangles(u, v, shape)]
    covered = triangle_map(corners, shape)
    gv, gu = np.mgrid[0 : shape[0], 0 : shape[1]]
    pix = np.stack([gu.ravel(), gv.ravel()], 1).astype(np.float64)
    a, b, c = (corners[:, k].astype(np.float64) for k in range(3))

    def side(p, q):  # pixels x triangles: which side of the directed side p -> q each pixel lies on
        return (q[None, :, 0] - p[None, :, 0]) * (pix[:, None, 1] - p[None, :, 1]) - (q[None, :, 1] - p[None, :, 1]) * (
            pix[:, None, 0] - p[None, :, 0]
        )

    s1, s2, s3 = side(a, b), side(b, c), side(c, a)
    # pixels x triangles, sides included
    inside = ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))
    flat = covered.ravel()
    assert ((flat >= 0) == inside.any(1)).all()  # covered exactly where some triangle holds the pixel
    hit = np.nonzero(flat >= 0)[0]
    assert inside[hit, flat[hit]].all()  # and by one that holds it
    # a pixel on a side two triangles share goes to the later one
    shared = np.nonzero(inside.sum(1) >= 2)[0]
    assert len(shared) and (flat[shared] == np.array([np.nonzero(row)[0].max() for row in inside[shared]])).all()


def _prior_mean_in_child(q, sparse, image):  # module level: the forked child runs it
    q.put(float(interpolated_fill(sparse, image=image).mean()))


def test_the_prior_runs_in_a_forked_child_after_its_parent_used_it():
    """The image guide runs in a helper thread; a data loader's forked worker inherits the parent's pool
    without its thread and must not wait on it forever."""
    import multiprocessing as mp

    rng = np.random.default_rng(4)
    img = rng.integers(0, 255, (60, 80, 3), dtype=np.uint8)
    sparse = np.where(rng.random((60, 80)) < 0.1, rng.uniform(3, 30, (60, 80)), 0).astype(np.float32)
    expected = float(interpolated_fill(sparse, image=img).mean())  # the parent uses the helper thread
    ctx = mp.get_context("fork")
    q = ctx.Queue()
    child = ctx.Process(target=_prior_mean_in_child, args=(q, sparse, img))
    child.start()
    child.join(30)
    alive = child.is_alive()
    if alive:
        child.kill()
    assert not alive, "the forked child hung on the parent's helper thread"
    assert q.get(timeout=5) == pytest.approx(expected)
