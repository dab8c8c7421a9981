"""Plane segmentation: the interface, the disparity-plane algebra, the geometric segmenter on
rendered ground truth and on the real EuRoC V1_01 pairs."""

from __future__ import annotations

import functools
import pathlib

import cv2
import numpy as np
import pytest

from backend.data.calibration import read_camera_yaml, stereo_rectification
from backend.data.euroc import read_indexed_poses
from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence
from backend.frontend.segmentation import NO_PLANE, PlaneMasks, PlaneSegmenter
from backend.frontend.segmentation_geometric import GeometricPlaneSegmenter, _condition_2x2, affine_disparity_to_plane, plane_to_affine_disparity
from backend.geometry.camera import PinholeCamera

PAIRS = pathlib.Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "euroc_v101_pairs" / "ForLoopClosureDetector"
FRAMES = (0, 50, 100, 150, 200, 250, 300, 350)  # of a 20 s room sequence: walls, floor, ceiling, box, sphere, cylinders


def test_plane_masks_checks_shapes() -> None:
    labels = np.full((4, 6), NO_PLANE, np.int16)
    labels[:2] = 0
    labels[2:, :3] = 1
    masks = PlaneMasks(labels=labels, normals_camera=np.zeros((2, 3)), offsets_camera=np.ones(2))
    assert masks.count == 2
    np.testing.assert_allclose(masks.fractions(), [0.5, 0.25])
    with pytest.raises(ValueError):
        PlaneMasks(labels=labels.astype(np.int32))
    with pytest.raises(ValueError):
        PlaneMasks(labels=labels, normals_camera=np.zeros((3, 3)), offsets_camera=np.ones(3))
    assert PlaneMasks(labels=np.full((2, 2), NO_PLANE, np.int16)).count == 0
    assert isinstance(GeometricPlaneSegmenter(), PlaneSegmenter)


def test_affine_disparity_matches_the_plane() -> None:
    camera = PinholeCamera(fx=458.0, fy=450.0, cx=367.0, cy=248.0, width=752, height=480, baseline=0.11)
    rng = np.random.default_rng(3)
    for _ in range(10):
        n_camera = rng.normal(size=3)
        n_camera[2] = -abs(n_camera[2]) - 0.3  # faces the camera
        n_camera /= np.linalg.norm(n_camera)
        d_camera = rng.uniform(0.5, 5.0)
        model = plane_to_affine_disparity(n_camera, d_camera, camera=camera)
        uv = rng.uniform([0, 0], [752, 480], size=(20, 2))
        x_hat = camera.normalize(uv)
        z = -d_camera / (x_hat @ n_camera)  # depth of the ray's intersection with the plane
        np.testing.assert_allclose(model[0] * uv[:, 0] + model[1] * uv[:, 1] + model[2], camera.fx * camera.baseline / z, rtol=1e-9)
        n_back, d_back = affine_disparity_to_plane(model, camera=camera)
        np.testing.assert_allclose(n_back, n_camera, atol=1e-12)
        assert d_back == pytest.approx(d_camera, rel=1e-12)


@functools.cache
def _synthetic() -> list[dict]:
    """Per frame: for each ground-truth plane over 5 % of the image, the best IoU and the
    normal error (degrees) of the best instance; the share of non-plane pixels on instances over
    5 %; the number of non-plane pixels."""
    seq = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=20.0), cache_frames=1)
    segmenter = GeometricPlaneSegmenter()
    results = []
    for k in FRAMES:
        left, right = seq.views(k)
        masks = segmenter.segment(left.image, right.image, seq.camera)
        R_world_camera = seq.T_world_rect0[k][:3, :3]
        planes = {}
        for plane_id in np.unique(left.plane_id[left.plane_id >= 0]):
            truth = left.plane_id == plane_id
            if truth.mean() < 0.05:
                continue
            iou = [np.count_nonzero(truth & masks.mask(i)) / np.count_nonzero(truth | masks.mask(i)) for i in range(masks.count)]
            best = int(np.argmax(iou)) if iou else None
            n_camera = R_world_camera.T @ seq.plane_table[int(plane_id)][:3]
            angle = np.degrees(np.arccos(min(1.0, abs(float(n_camera @ masks.normals_camera[best]))))) if best is not None else 180.0
            planes[int(plane_id)] = (iou[best] if iou else 0.0, angle, truth.mean())
        large = np.flatnonzero(masks.fractions() > 0.05)
        off_plane = left.plane_id == NO_PLANE
        results.append({"frame": k, "planes": planes, "off_plane_on_large": float(np.isin(masks.labels[off_plane], large).mean()) if off_plane.any() else 0.0, "off_plane": int(off_plane.sum())})
    return results


def test_geometric_segmenter_recovers_rendered_planes() -> None:
    results = _synthetic()
    recovered = [iou >= 0.6 and angle < 10.0 for r in results for iou, angle, _ in r["planes"].values()]
    # The largest plane of every frame: measured IoU 0.78-0.99, normal error < 2°.
    for r in results:
        iou, angle, _ = max(r["planes"].values(), key=lambda p: p[2])
        assert iou > 0.7 and angle < 5.0, r
    # All planes over 5 %: measured 68 % (15 of 22) recovered (misses: far walls seen at grazing angles,
    # floor strips at the image border).
    assert np.mean(recovered) >= 0.55, results
    # Good matches are accurate: median normal error measured ~1°.
    angles = [angle for r in results for iou, angle, _ in r["planes"].values() if iou >= 0.6]
    assert np.median(angles) < 3.0


def test_geometric_segmenter_leaves_curved_surfaces_mostly_unassigned() -> None:
    shares = [r["off_plane_on_large"] for r in _synthetic() if r["off_plane"] > 0.01 * 752 * 480]
    assert shares, "no frame shows the sphere or the cylinders"
    # Measured 0.01, 0.01, 0.22: a cylinder standing on the floor can join the floor's region.
    assert np.median(shares) < 0.2, shares


def test_geometric_segmenter_finds_floor_and_walls_on_euroc() -> None:
    if not PAIRS.is_dir():
        pytest.skip(f"EuRoC pairs not found at {PAIRS}")
    rect = stereo_rectification(read_camera_yaml(PAIRS / "sensorLeft.yaml"), read_camera_yaml(PAIRS / "sensorRight.yaml"))
    poses = read_indexed_poses(PAIRS / "groundtruth_from_openvins_original.txt")
    segmenter = GeometricPlaneSegmenter()
    for i, T_world_body in sorted(poses.items()):
        raw0 = cv2.imread(str(PAIRS / f"left_img_{i}.png"), cv2.IMREAD_GRAYSCALE)
        raw1 = cv2.imread(str(PAIRS / f"right_img_{i}.png"), cv2.IMREAD_GRAYSCALE)
        masks = segmenter.segment(*rect.rectify(raw0, raw1), rect.camera)
        R_world_rect0 = (T_world_body @ rect.T_body_rect0)[:3, :3]
        n_world = masks.normals_camera @ R_world_rect0.T
        large = masks.fractions() > 0.05
        tilt_deg = np.degrees(np.arccos(np.clip(np.abs(n_world[:, 2]), 0.0, 1.0)))
        assert np.count_nonzero(large) >= 2, (i, masks.fractions())
        # The floor: a large plane whose normal is within 10° of the world's vertical
        # (measured 1-4°); a wall or panel: a large one within 30° of horizontal.
        assert np.any(large & (tilt_deg < 10.0)), (i, tilt_deg, masks.fractions())
        assert np.any(large & (tilt_deg > 60.0)), (i, tilt_deg, masks.fractions())


def _reference_component(disp0, free, model, threshold, seed) -> tuple[np.ndarray, bool]:
    """What the segmenter chose before the flood: the 4-connected component of the fitting
    pixels over the whole image with the most pixels in the seed block (OpenCV's labels),
    and whether another component had as many."""
    h, w = disp0.shape
    v_grid, u_grid = np.mgrid[0:h, 0:w].astype(np.float32)
    inliers = free & (np.abs(disp0 - (model[0] * u_grid + model[1] * v_grid + model[2])) < threshold)
    count, components = cv2.connectedComponents(inliers.view(np.uint8), connectivity=4)
    hits = np.bincount(components[seed].ravel(), minlength=count)
    hits[0] = 0
    if hits.max() == 0:
        return np.empty(0, np.int64), False
    return np.flatnonzero(components.reshape(-1) == int(hits.argmax())), int(np.sum(hits == hits.max())) > 1


def test_the_flood_grows_the_component_the_whole_image_pass_would() -> None:
    """The segmenter floods only the components that touch a seed block instead of labelling
    the whole image; it must choose the same pixels, in either precision of the model (seed
    models are float64, refitted ones float32), ties between components included."""
    from backend.frontend.segmentation_geometric import _flood

    rng = np.random.default_rng(7)
    h, w, block = 60, 90, 9  # an odd block: a wall through its middle column leaves halves of equal size
    mark = np.zeros((h, w), np.int32)
    stack, runs, out = np.empty((2 * h * w, 2), np.int32), np.empty((h * w, 3), np.int32), np.empty(h * w, np.int64)
    columns, rows = np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)
    ties = 0
    for trial in range(300):
        model64 = np.array([rng.normal(0, 0.05), rng.normal(0, 0.05), rng.uniform(5, 30)])
        model = model64.astype(np.float32) if trial % 2 else model64
        v_grid, u_grid = np.mgrid[0:h, 0:w]
        disp0 = (model64[0] * u_grid + model64[1] * v_grid + model64[2] + rng.normal(0, rng.uniform(0.05, 0.6), (h, w))).astype(np.float32)
        free = rng.random((h, w)) > rng.uniform(0.0, 0.5)
        r, c = rng.integers(0, h // block), rng.integers(0, w // block)
        if trial % 5 == 0:  # a wall of misfits through the block, the rest fitting: two components, as many hits each
            disp0 = (model64[0] * u_grid + model64[1] * v_grid + model64[2]).astype(np.float32)
            free[:] = True
            free[:, c * block + block // 2] = False
        seed = (slice(r * block, (r + 1) * block), slice(c * block, (c + 1) * block))
        threshold = 0.5 if trial % 3 else 1.0
        expected, tie = _reference_component(disp0, free, model, threshold, seed)
        dtype = model.dtype
        block_rows, block_cols = (r * block, (r + 1) * block), (c * block, (c + 1) * block)
        size = _flood(disp0.astype(dtype), free, columns.astype(dtype), rows.astype(dtype), model, dtype.type(threshold), *block_rows, *block_cols, mark, stack, runs, out)
        np.testing.assert_array_equal(out[:size], expected, err_msg=f"trial {trial}")
        assert not mark.any()  # the scratch is left clean for the next flood
        ties += tie
    assert ties >= 10, ties  # the tie-break was exercised


def test_the_fits_condition_number_is_numpys() -> None:
    """The region fit's closed-form condition number of its 2×2 normal matrix agrees with
    `np.linalg.cond`, down to the singular matrices it rejects."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        A = rng.normal(size=(50, 2)) * rng.uniform(1e-3, 1e3, size=2)
        M = A.T @ A
        assert _condition_2x2(M[0, 0], M[0, 1], M[1, 1]) == pytest.approx(np.linalg.cond(M), rel=1e-6)
    assert _condition_2x2(4.0, 2.0, 1.0) == float("inf")  # rank one: u and v along one line
    assert _condition_2x2(0.0, 0.0, 0.0) == float("inf")
