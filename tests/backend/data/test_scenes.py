"""The built-in scenes: the standard ones render exactly as they always have, every stress
scene renders and stresses what it says (hand shake, a still start, faint texture,
auto-exposure), and scene files round-trip the rig, motion and exposure, refusing bad
values in one line."""

from __future__ import annotations

import hashlib
import json
import pathlib

import cv2
import numpy as np
import pytest

from backend.data import scenes
from backend.data.motion import GRAVITY_WORLD
from backend.data.scenes import SceneFileError, builtin_scene, load_scene, scene_to_dict, scene_to_json
from backend.data.synthetic import SequenceSettings, SyntheticSequence

# computed at commit 1518d0f, before scenes had rigs, motions and exposures
STANDARD_FINGERPRINTS = {"room": "c58a275f7bef61fc", "corridor": "2d7cba1a7fc0c72f", "boxes": "c08d1adccc7bcf10"}


def _fingerprint(name: str) -> str:
    """sha256 (16 hex digits) of three frames' images, depths and plane ids (both views),
    the timestamps, the body poses and the noisy IMU, with image noise and exposure on."""
    seq = SyntheticSequence(builtin_scene(name), settings=SequenceSettings(duration_s=2.0, seed=4, image_noise=1.5, exposure=0.2))
    h = hashlib.sha256()
    for i in (0, 17, 40):
        for view in seq.views(i):
            h.update(view.image.tobytes())
            h.update(view.depth.tobytes())
            h.update(view.plane_id.tobytes())
    for a in (seq.timestamps_ns, seq.T_world_body, seq.imu.timestamp_ns, seq.imu.gyro, seq.imu.accel):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


@pytest.mark.parametrize("name", scenes.STANDARD_SCENES)
def test_standard_scenes_render_bit_for_bit_as_before(name: str) -> None:
    assert _fingerprint(name) == STANDARD_FINGERPRINTS[name]


@pytest.mark.parametrize("name", scenes.STRESS_SCENES)
def test_every_stress_scene_renders_with_its_truth(name: str) -> None:
    scene = builtin_scene(name)
    assert scene.name == name and name in scenes.SCENE_NAMES
    seq = SyntheticSequence(scene, settings=SequenceSettings(duration_s=2.0))
    assert seq.camera == scene.rig.camera and len(seq) == int(2.0 * scene.rig.camera_rate_hz) + 1
    for k in (0, len(seq) - 1):
        left, right = seq.views(k)
        assert left.image.shape == (seq.camera.height, seq.camera.width) and left.image.std() > 5
        assert np.mean(left.plane_id >= 0) > 0.3 and np.mean(np.isfinite(left.depth)) > 0.5
        assert set(np.unique(left.plane_id[left.plane_id >= 0])) <= set(seq.plane_table)
        assert not np.array_equal(left.image, right.image)


def _room_and(name: str, duration_s: float) -> tuple[SyntheticSequence, SyntheticSequence]:
    settings = SequenceSettings(duration_s=duration_s)
    return SyntheticSequence(builtin_scene("room"), settings=settings), SyntheticSequence(builtin_scene(name), settings=settings)


def test_shake_adds_a_hand_held_shake_at_2_to_6_hz() -> None:
    """Against `room` (the same path): the difference is a shake of up to 8 mm and 1.5° per
    axis, nearly all of its power between 2 and 6 Hz; room's own path has none there."""
    room, shake = _room_and("shake", 20.0)
    t = np.arange(0.0, 20.0, 0.005)
    dp = shake.trajectory.position(t) - room.trajectory.position(t)
    assert 0.003 < np.max(np.abs(dp)) <= 0.008 + 1e-12
    R = np.swapaxes(room.trajectory.rotation(t), 1, 2) @ shake.trajectory.rotation(t)
    angle = np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert 0.5 < angle.max() < 3.0
    freq = np.fft.rfftfreq(len(t), 0.005)
    band = (freq >= 1.9) & (freq <= 6.1)
    window = np.hanning(len(t))[:, None]
    spectrum = lambda x: np.sum(np.abs(np.fft.rfft((x - x.mean(axis=0)) * window, axis=0)) ** 2, axis=1)  # noqa: E731
    power = spectrum(dp)
    assert power[band].sum() / power.sum() > 0.95
    assert spectrum(room.trajectory.position(t))[band].sum() < 1e-3 * power[band].sum()
    # the IMU feels it (RMS differences from room's readings)
    rms = lambda x: float(np.sqrt(np.mean(np.sum(x**2, axis=1))))  # noqa: E731
    assert rms(shake.imu_true.gyro - room.imu_true.gyro) > 0.2 and rms(shake.imu_true.accel - room.imu_true.accel) > 1.0


def test_slow_start_is_nearly_still_for_3_s_then_moves_as_usual() -> None:
    _, slow = _room_and("slow-start", 10.0)
    early = np.arange(0.0, 3.0, 0.005)
    assert np.max(np.linalg.norm(slow.trajectory.velocity(early), axis=1)) < 0.005  # under 5 mm/s
    gyro = slow.imu_true.between(-1, int(3e9)).gyro
    assert np.max(np.linalg.norm(gyro, axis=1)) < 0.01  # rad/s
    accel = slow.imu_true.between(-1, int(3e9)).accel
    np.testing.assert_allclose(np.linalg.norm(accel, axis=1), -GRAVITY_WORLD[2], atol=0.01)  # no excitation: gravity only
    late = np.arange(6.0, 10.0, 0.005)
    assert np.median(np.linalg.norm(slow.trajectory.velocity(late), axis=1)) > 0.1


def test_low_texture_walls_are_barely_trackable() -> None:
    """On the walls, floor and ceiling (planes 0-5; a door included), a tenth of the ORB corners that
    `room` has there (at the pipeline's FAST threshold, 10), but some in most frames."""
    room, low = _room_and("low-texture", 15.0)
    orb = cv2.ORB_create(1000, fastThreshold=10)  # type: ignore[attr-defined]  # not in OpenCV's stubs

    def on_surfaces(seq: SyntheticSequence) -> list[int]:
        counts = []
        for k in range(0, len(seq), 15):
            view = seq.views(k)[0]
            uv = np.array([p.pt for p in orb.detect(view.image, None)]).reshape(-1, 2).round().astype(int)
            ids = view.plane_id[np.clip(uv[:, 1], 0, view.image.shape[0] - 1), np.clip(uv[:, 0], 0, view.image.shape[1] - 1)]
            counts.append(int(np.sum((ids >= 0) & (ids <= 5))))
        return counts

    rich, faint = on_surfaces(room), on_surfaces(low)
    assert sum(faint) < 0.1 * sum(rich) and np.median(rich) > 500
    assert np.median(faint) >= 5


def test_exposure_steps_and_ramps_the_gain() -> None:
    """The same pictures as `room` times the schedule's gain (steps and ramps between 0.55
    and 1.5); depth and plane ids unchanged."""
    room, exposed = _room_and("exposure", 16.0)
    schedule = exposed.scene.exposure
    assert schedule is not None
    gains = np.array([schedule.gain(t * 1e-9) for t in exposed.timestamps_ns])
    assert gains.min() <= 0.6 and gains.max() >= 1.45
    assert np.max(np.abs(np.diff(gains))) > 0.4  # a step between two frames
    assert np.sum((np.diff(gains) != 0) & (np.abs(np.diff(gains)) < 0.1)) > 20  # ramps
    for k in (10, 80, 120, 230):  # gains 1.0, 0.6, 1.0, 0.55 ... wherever they fall
        a, b = room.views(k)[0], exposed.views(k)[0]
        np.testing.assert_array_equal(a.depth, b.depth)
        unsaturated = a.image.astype(float) * gains[k] < 250
        ratio = b.image[unsaturated].astype(float).sum() / a.image[unsaturated].astype(float).sum()
        assert ratio == pytest.approx(gains[k], rel=0.02)


@pytest.mark.parametrize("name", ["street", "shake", "slow-start", "exposure"])
def test_scene_files_round_trip_rig_motion_and_exposure(tmp_path: pathlib.Path, name: str) -> None:
    scene = builtin_scene(name)
    path = tmp_path / f"{name}.json"
    path.write_text(scene_to_json(scene))
    loaded = load_scene(path)
    assert scene_to_dict(loaded) == json.loads(path.read_text())
    assert loaded.motion == scene.motion and loaded.exposure == scene.exposure
    settings = SequenceSettings(duration_s=1.0, seed=3)
    a, b = SyntheticSequence(scene, settings=settings), SyntheticSequence(loaded, settings=settings)
    assert a.camera == b.camera and a.camera_rate_hz == b.camera_rate_hz
    np.testing.assert_array_equal(a.T_world_body, b.T_world_body)
    np.testing.assert_array_equal(a.imu.accel, b.imu.accel)
    np.testing.assert_array_equal(a.views(5)[0].image, b.views(5)[0].image)


def test_scene_files_without_the_new_fields_keep_the_defaults(tmp_path: pathlib.Path) -> None:
    data = scene_to_dict(builtin_scene("room"))
    for key in ("rig", "motion", "exposure"):
        del data[key]
    path = tmp_path / "old.json"
    path.write_text(json.dumps(data))
    loaded = load_scene(path)
    assert loaded.rig is scenes.EUROC_RIG and loaded.motion == scenes.Motion() and loaded.exposure is None


@pytest.mark.parametrize(
    ("scene", "edit", "expected"),
    [
        ("street", lambda d: d["rig"]["camera"].update(width=8), "rig.camera: width and height"),
        ("street", lambda d: d["rig"]["camera"].update(fx="wide"), "rig.camera.fx: expected a number"),
        ("street", lambda d: d["rig"].update(camera_rate_hz=-10), "rig.camera_rate_hz: expected a number in (0, 1000]"),
        ("street", lambda d: d["rig"]["T_body_cam0"][0].__setitem__(0, 3.0), "rig.T_body_cam0: expected a rigid transform"),
        ("street", lambda d: d["motion"]["road"].update(speed_mps=[20, 10]), "motion.road.speed_mps: expected [in corners, on straights]"),
        ("street", lambda d: d["motion"]["road"].pop("corner_m"), "motion.road: missing 'corner_m'"),
        ("street", lambda d: d.update(motion=[]), "motion: expected an object"),
        ("shake", lambda d: d["motion"]["shake"].update(band_hz=[6, 2]), "motion.shake.band_hz: expected [low, high]"),
        ("slow-start", lambda d: d["motion"]["slow_start"].update(creep=2), "motion.slow_start.creep: expected a number in [0, 1]"),
        ("exposure", lambda d: d["exposure"]["changes"][1].update(at_s=0.5), "exposure.changes: expected increasing at_s"),
        ("exposure", lambda d: d["exposure"]["changes"][0].update(gain=0), "exposure.changes[0].gain: expected a number in (0, 10]"),
        ("exposure", lambda d: d["exposure"].update(period_s=2.0), "exposure.changes[1].at_s: must be in [0, period_s)"),
        ("exposure", lambda d: d.update(exposure=5), "exposure: expected an object"),
    ],
)
def test_bad_rig_motion_or_exposure_is_one_line(tmp_path: pathlib.Path, scene: str, edit, expected: str) -> None:
    data = scene_to_dict(builtin_scene(scene))
    edit(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(SceneFileError) as error:
        load_scene(path)
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"{path}: ") and expected in message, message
