"""Synthetic scenes and the homography renderer: exact depth, plane masks, stereo geometry,
features for ORB/LSD, determinism, scene files."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from backend.data import render, scenes, textures
from backend.data.scenes import Rectangle, Scene, SceneFileError, Texture, facing_rectangle
from backend.geometry.camera import PinholeCamera

CAMERA = PinholeCamera(fx=458.0, fy=458.0, cx=367.0, cy=248.0, width=752, height=480, baseline=0.11)


@pytest.fixture(scope="module")
def room() -> Scene:
    return scenes.builtin_scene("room")


@pytest.fixture(scope="module")
def room_view(room: Scene) -> tuple[np.ndarray, np.ndarray, render.View]:
    """A view from the room's middle towards the +x wall, slightly down."""
    t_world_camera = np.array([-0.5, -0.8, 1.5])
    R_world_camera = render.look_at(t_world_camera, np.array([3.0, 0.3, 0.9]))
    return R_world_camera, t_world_camera, render.render_view(room, CAMERA, R_world_camera, t_world_camera)


def _pixel_rays(camera: PinholeCamera) -> np.ndarray:
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    return camera.normalize(np.stack([u, v], axis=-1).astype(float))


def _points_world(view: render.View, R_world_camera: np.ndarray, t_world_camera: np.ndarray) -> np.ndarray:
    """World points (H, W, 3) of every pixel from the rendered depth."""
    depth = np.where(np.isfinite(view.depth), view.depth, 0.0).astype(float)
    return (_pixel_rays(CAMERA) * depth[..., None]) @ R_world_camera.T + t_world_camera


def test_fronto_parallel_wall_depth_is_exact() -> None:
    wall = facing_rectangle(np.array([0.3, -0.2, 4.0]), np.array([0.0, 0.0, -1.0]), (2.0, 1.5), Texture("poster", 1), 7)
    scene = Scene(name="wall", rectangles=(wall,))
    view = render.render_view(scene, CAMERA, np.eye(3), np.zeros(3))
    on_wall = view.plane_id == 7
    assert on_wall.sum() > 0.1 * on_wall.size
    np.testing.assert_allclose(view.depth[on_wall], 4.0, rtol=1e-6)
    assert np.all(np.isinf(view.depth[~on_wall]))
    assert np.all(view.image[~on_wall] == render.BACKGROUND_GREY)
    # its projected outline: x ∈ [-0.7, 1.3], y ∈ [-0.95, 0.55] at z = 4
    u = CAMERA.fx * np.array([-0.7, 1.3]) / 4.0 + CAMERA.cx
    v = CAMERA.fy * np.array([-0.95, 0.55]) / 4.0 + CAMERA.cy
    cols = np.flatnonzero(on_wall.any(axis=0))
    rows = np.flatnonzero(on_wall.any(axis=1))
    assert abs(cols[0] - u[0]) <= 1 and abs(cols[-1] - u[1]) <= 1
    assert abs(rows[0] - v[0]) <= 1 and abs(rows[-1] - v[1]) <= 1


def test_room_corner_view_sees_floor_and_both_walls(room: Scene) -> None:
    t_world_camera = np.array([0.0, 0.0, 1.5])
    R_world_camera = render.look_at(t_world_camera, np.array([3.0, 2.5, 0.6]))
    view = render.render_view(room, CAMERA, R_world_camera, t_world_camera)
    ids = set(np.unique(view.plane_id).tolist())
    assert {0, 2, 4} <= ids  # floor, the x = +3 wall, the y = +2.5 wall
    assert 1 not in ids and 5 not in ids  # not the ceiling at this pitch, not the wall behind
    assert np.all(np.isfinite(view.depth))  # a closed room: every pixel hits something


def test_depth_and_plane_ids_agree_with_the_plane_table(room: Scene, room_view) -> None:
    R_world_camera, t_world_camera, view = room_view
    p_world = _points_world(view, R_world_camera, t_world_camera)
    planes = room.planes
    ids = [i for i in np.unique(view.plane_id).tolist() if i >= 0]
    assert len(ids) >= 3
    for plane_id in ids:
        on = view.plane_id == plane_id
        n, d = planes[plane_id][:3], planes[plane_id][3]
        residual = p_world[on] @ n + d
        assert np.max(np.abs(residual) / view.depth[on]) < 1e-4, plane_id


def test_non_planar_pixels_lie_on_the_sphere_and_cylinder(room: Scene) -> None:
    sphere = room.spheres[0]
    cylinder = room.cylinders[0]
    t_world_camera = np.array([0.0, 0.0, 1.4])
    for target, check in (
        (sphere.centre, lambda p: np.abs(np.linalg.norm(p - sphere.centre, axis=-1) - sphere.radius)),
        (np.array([*cylinder.centre_xy, 0.6]), lambda p: np.minimum(np.abs(np.linalg.norm(p[:, :2] - cylinder.centre_xy, axis=-1) - cylinder.radius), np.abs(p[:, 2] - cylinder.z_range[1]))),
    ):
        R_world_camera = render.look_at(t_world_camera, target)
        view = render.render_view(room, CAMERA, R_world_camera, t_world_camera)
        p_world = _points_world(view, R_world_camera, t_world_camera)
        centre = view.plane_id[CAMERA.height // 2, CAMERA.width // 2]
        assert centre == render.NON_PLANAR_ID and np.isfinite(view.depth[CAMERA.height // 2, CAMERA.width // 2])
        # the non-planar region around the image centre
        _, labels = cv2.connectedComponents((view.plane_id == -1).astype(np.uint8))
        blob = labels == labels[CAMERA.height // 2, CAMERA.width // 2]
        assert blob.sum() > 500
        assert np.median(check(p_world[blob])) < 1e-4
        assert np.percentile(check(p_world[blob]), 99) < 5e-3


def test_world_point_on_a_rectangle_projects_to_its_depth_and_plane(room: Scene) -> None:
    rect = next(r for r in room.rectangles if r.texture.kind == "poster" and r.plane_id == 2)
    w, h = rect.size
    p_world = rect.p0 + 0.3 * w * rect.u + 0.6 * h * rect.v
    t_world_camera = p_world + 2.0 * rect.normal + np.array([0.0, 0.3, 0.2])
    R_world_camera = render.look_at(t_world_camera, p_world)
    view = render.render_view(room, CAMERA, R_world_camera, t_world_camera)
    # on the optical axis: it projects exactly to the principal point (367, 248)
    z = float((R_world_camera.T @ (p_world - t_world_camera))[2])
    assert view.plane_id[248, 367] == rect.plane_id
    assert view.depth[248, 367] == pytest.approx(z, rel=1e-6)
    # other points of the rectangle: the nearest pixel's depth within the depth change over half a pixel
    rng = np.random.default_rng(3)
    for a, b in rng.uniform(0.1, 0.9, (20, 2)):
        p = rect.p0 + a * w * rect.u + b * h * rect.v
        p_camera = R_world_camera.T @ (p - t_world_camera)
        u, v = np.round(CAMERA.project(p_camera)).astype(int)
        assert view.plane_id[v, u] == rect.plane_id
        assert view.depth[v, u] == pytest.approx(p_camera[2], rel=5e-3)


def test_rectangle_partly_behind_the_camera_is_clipped_with_exact_depth() -> None:
    floor = facing_rectangle(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), (20.0, 20.0), Texture("tiles", 4), 0)
    scene = Scene(name="floor", rectangles=(floor,))
    height = 1.5
    t_world_camera = np.array([0.0, 0.0, height])
    R_world_camera = render.R_BODY_CAMERA_FORWARD  # looking along +x, horizontally
    view = render.render_view(scene, CAMERA, R_world_camera, t_world_camera)
    v = np.arange(CAMERA.height)[:, None] * np.ones((1, CAMERA.width))
    below = v > CAMERA.cy + 80  # horizon at row cy; the floor ends 10 m away (row cy + 69)
    assert np.all(view.plane_id[below] == 0)
    np.testing.assert_allclose(view.depth[below], height * CAMERA.fy / (v[below] - CAMERA.cy), rtol=1e-5)
    assert np.all(view.plane_id[: int(CAMERA.cy)] == -1)  # sky above the horizon
    # and a wall that the camera stands in front of, reaching behind it
    wall = facing_rectangle(np.array([0.0, 1.0, 1.0]), np.array([0.0, -1.0, 0.0]), (6.0, 2.0), Texture("plaster", 5), 1)
    view = render.render_view(Scene(name="wall", rectangles=(wall,)), CAMERA, R_world_camera, t_world_camera)
    p_world = _points_world(view, R_world_camera, t_world_camera)
    on = view.plane_id == 1
    assert on.sum() > 1000
    np.testing.assert_allclose(p_world[on][:, 1], 1.0, atol=1e-4)


def test_stereo_pair_is_geometrically_consistent(room: Scene, room_view) -> None:
    R_world_left, t_world_left, _ = room_view
    left, right = render.render_stereo(room, CAMERA, R_world_left, t_world_left)
    v, u = np.mgrid[0 : CAMERA.height, 0 : CAMERA.width].astype(np.float32)
    disparity = CAMERA.fx * CAMERA.baseline / left.depth
    map_u = (u - disparity).astype(np.float32)
    right_at = cv2.remap(right.image, map_u, v, cv2.INTER_LINEAR, borderValue=0)
    right_depth_at = cv2.remap(right.depth, map_u, v, cv2.INTER_NEAREST, borderValue=0)
    usable = (left.plane_id >= 0) & (map_u > 1) & (np.abs(right_depth_at - left.depth) < 1e-3 * left.depth)
    assert usable.sum() > 0.5 * usable.size
    difference = np.abs(right_at[usable].astype(float) - left.image[usable])
    assert np.median(difference) <= 6.0
    # and mis-registration by 2 px is much worse: the check has teeth
    shifted = cv2.remap(right.image, map_u + 2.0, v, cv2.INTER_LINEAR, borderValue=0)
    assert np.median(np.abs(shifted[usable].astype(float) - left.image[usable])) > 2 * np.median(difference)
    # the right camera's plane ids agree where it sees the same surface
    right_ids = cv2.remap(right.plane_id.astype(np.float32), map_u, v, cv2.INTER_NEAREST)
    assert np.mean(right_ids[usable] == left.plane_id[usable]) > 0.99


def test_rendering_and_textures_are_deterministic_per_seed(room: Scene, room_view) -> None:
    R_world_camera, t_world_camera, view = room_view
    options = dict(gain=1.2, blur_sigma_px=0.8, noise_sigma=3.0)
    a = render.render_view(room, CAMERA, R_world_camera, t_world_camera, rng=np.random.default_rng(5), **options)
    b = render.render_view(room, CAMERA, R_world_camera, t_world_camera, rng=np.random.default_rng(5), **options)
    c = render.render_view(room, CAMERA, R_world_camera, t_world_camera, rng=np.random.default_rng(6), **options)
    assert np.array_equal(a.image, b.image) and not np.array_equal(a.image, c.image)
    assert np.array_equal(a.depth, view.depth) and np.array_equal(a.plane_id, view.plane_id)
    assert np.array_equal(render.render_view(room, CAMERA, R_world_camera, t_world_camera).image, view.image)
    for kind in textures.KINDS:
        first = textures.texture_image.__wrapped__(kind, 3, 120, 200)
        assert first.dtype == np.uint8 and first.shape == (120, 200)
        assert np.array_equal(first, textures.texture_image.__wrapped__(kind, 3, 120, 200))
        assert not np.array_equal(first, textures.texture_image.__wrapped__(kind, 4, 120, 200))
    with pytest.raises(ValueError, match="rng"):
        render.render_view(room, CAMERA, R_world_camera, t_world_camera, noise_sigma=1.0)


def test_a_registered_texture_kind_is_rendered_and_built_ins_stay(monkeypatch: pytest.MonkeyPatch) -> None:
    """A kind made elsewhere (the segmenter's training photographs) joins for the process:
    scenes with it pass validation and render with its image; built-ins cannot be replaced."""
    monkeypatch.setattr(textures, "_REGISTERED", {})
    stripes = lambda rng, shape: np.tile(np.where(np.arange(shape[1]) % 40 < 20, 30, 220).astype(np.uint8), (shape[0], 1))  # noqa: E731
    with pytest.raises(ValueError, match="texture.kind"):
        Scene(name="x", rectangles=(facing_rectangle(np.array([0.0, 0.0, 3.0]), np.array([0.0, 0.0, -1.0]), (4.0, 4.0), Texture("stripes", 0), 0),))
    textures.register_texture("stripes", stripes)
    assert textures.known_kinds() == (*textures.KINDS, "stripes")
    wall = facing_rectangle(np.array([0.0, 0.0, 3.0]), np.array([0.0, 0.0, -1.0]), (40.0, 40.0), Texture("stripes", 0), 0)
    view = render.render_view(Scene(name="x", rectangles=(wall,)), CAMERA, np.eye(3), np.zeros(3))
    assert np.all(view.plane_id == 0) and view.image.min() < 60 and view.image.max() > 190
    with pytest.raises(ValueError, match="built-in"):
        textures.register_texture("tiles", stripes)
    textures.texture_image.cache_clear()


def test_orb_and_lsd_find_features_in_a_room_view(room_view) -> None:
    _, _, view = room_view
    keypoints = cv2.ORB_create(1000).detect(view.image, None)
    assert len(keypoints) > 300
    if not hasattr(cv2, "createLineSegmentDetector"):
        pytest.skip("this OpenCV build has no LineSegmentDetector (ORB part passed)")
    lines = cv2.createLineSegmentDetector().detect(view.image)[0]
    assert lines is not None and len(lines) > 50


@pytest.mark.parametrize("name", scenes.SCENE_NAMES)
def test_builtin_scenes_have_planes_and_non_planar_objects(name: str) -> None:
    scene = scenes.builtin_scene(name)
    assert scene.spheres or scene.cylinders
    assert len(scene.planes) >= 6
    for plane in scene.planes.values():
        assert abs(np.linalg.norm(plane[:3]) - 1.0) < 1e-12
    for rect in scene.rectangles:  # every corner on its plane
        plane = scene.planes[rect.plane_id]
        assert np.max(np.abs(rect.corners @ plane[:3] + plane[3])) < 1e-9
    centre, half_extent = scene.camera_region
    R_world_camera = render.R_BODY_CAMERA_FORWARD
    view = render.render_view(scene, CAMERA, R_world_camera, centre)
    assert (view.plane_id >= 0).mean() > 0.3


def test_scene_json_round_trip(tmp_path, room: Scene, room_view) -> None:
    path = tmp_path / "room.json"
    path.write_text(scenes.scene_to_json(room))
    loaded = scenes.load_scene(path)
    assert loaded.name == room.name and len(loaded.rectangles) == len(room.rectangles)
    assert len(loaded.spheres) == len(room.spheres) and len(loaded.cylinders) == len(room.cylinders)
    for a, b in zip(loaded.rectangles, room.rectangles, strict=True):
        assert a.texture == b.texture and a.plane_id == b.plane_id and a.size == b.size
        np.testing.assert_array_equal(a.corners, b.corners)
    R_world_camera, t_world_camera, view = room_view
    again = render.render_view(loaded, CAMERA, R_world_camera, t_world_camera)
    assert np.array_equal(again.image, view.image) and np.array_equal(again.depth, view.depth)


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda d: d["rectangles"][1].update(u=[1.0, 0.0]), "rectangles[1].u: expected 3 numbers"),
        (lambda d: d["rectangles"][0].update(v=[1.0, 0.0, 0.0]), "rectangles[0]: u and v must be orthogonal"),
        (lambda d: d["rectangles"][0]["texture"].update(kind="marble"), "rectangles[0].texture.kind: unknown 'marble'"),
        (lambda d: d["rectangles"][3].update(plane_id=2), "rectangles[3]: plane_id 2 is shared with rectangles[2]"),
        (lambda d: d["spheres"][0].update(radius=-1.0), "spheres[0]"),
        (lambda d: d.pop("rectangles"), "rectangles: expected at least one rectangle"),
    ],
)
def test_malformed_scene_file_gives_a_one_line_error(tmp_path, room: Scene, edit, expected: str) -> None:
    data = scenes.scene_to_dict(room)
    edit(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(SceneFileError) as error:
        scenes.load_scene(path)
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"{path}: ") and expected in message
    assert isinstance(error.value, ValueError)


def test_unreadable_scene_files(tmp_path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"rectangles": [\n  {"p0": [0, 0, 0],,}]}')
    with pytest.raises(SceneFileError, match=r"bad\.json: invalid JSON at line 2"):
        scenes.load_scene(bad)
    with pytest.raises(SceneFileError, match="missing file"):
        scenes.load_scene(tmp_path / "absent.json")
    with pytest.raises(ValueError, match="unknown scene"):
        scenes.builtin_scene("castle")


def test_rectangle_validation_in_code() -> None:
    with pytest.raises(ValueError, match="unit"):
        Scene(name="x", rectangles=(Rectangle(np.zeros(3), np.array([2.0, 0, 0]), np.array([0, 1.0, 0]), (1.0, 1.0), Texture("tiles", 0), 0),))
