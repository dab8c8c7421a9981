"""The sweep's matrix (backend/sweep/matrix.py): axes from options and from TOML, the runs
they span, their folder names, and bad values as one line naming the option or key."""

from __future__ import annotations

import pathlib

import pytest

from backend.data.scenes import builtin_scene, scene_to_json
from backend.optim.variant import VARIANTS, Variant
from backend.pipeline.factory import Mode
from backend.sweep.matrix import MatrixError, SweepMatrix, matrix_from, parse_axes, read_toml


def test_defaults_are_the_built_in_scenes_with_every_variant() -> None:
    runs = SweepMatrix().runs()
    assert [r.run_id for r in runs[:2]] == ["room_P-wo_stereo_geometric_seed0_30s", "room_P-r_stereo_geometric_seed0_30s"]
    assert len(runs) == 3 * len(VARIANTS) and {r.input_name for r in runs} == {"room", "corridor", "boxes"}


def test_options_span_the_product_and_name_each_run() -> None:
    fields = parse_axes({"scenes": "room,corridor", "variants": "P-wo,PL-w", "modes": "stereo,vio", "seeds": "0-2,7", "speeds": "1,2", "duration": "4"})
    runs = SweepMatrix(**fields).runs()
    assert len(runs) == 2 * 2 * 2 * 4 * 2
    ids = [r.run_id for r in runs]
    assert len(set(ids)) == len(ids)
    assert "corridor_PL-w_vio_learned_seed7_4s_speed2" in ids  # VIO's default segmenter, resolved
    config = next(r for r in runs if r.run_id == "corridor_PL-w_vio_learned_seed7_4s_speed2").config()
    assert (config.scene, config.variant, config.mode, config.seed, config.speed, config.duration_s) == ("corridor", Variant.PL_W, Mode.VIO, 7, 2.0, 4.0)
    assert not config.interactive


def test_datasets_are_run_as_recorded(tmp_path: pathlib.Path) -> None:
    (tmp_path / "MH_01" / "mav0").mkdir(parents=True)
    runs = matrix_from(None, {"datasets": str(tmp_path / "MH_01" / "mav0"), "variants": "PL-w", "speeds": "1,3", "strides": "1,2", "frames": "50"}).runs()
    assert [r.run_id for r in runs] == ["MH_01_PL-w_stereo_geometric_seed0_frames50"]  # speeds and strides: rendered scenes only
    config = runs[0].config()
    assert config.dataset == str(tmp_path / "MH_01" / "mav0") and config.scene is None and config.frames == 50


def test_toml_file_with_options_taking_its_place(tmp_path: pathlib.Path) -> None:
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "hall.json").write_text(scene_to_json(builtin_scene("boxes")))
    config = tmp_path / "sweep.toml"
    config.write_text('scenes = ["room", "scenes/hall.json"]\nvariants = "all"\nseeds = "0-1"\nmodes = ["stereo"]\nstrides = [1, 2]\nduration = 1.5\n')
    matrix = matrix_from(read_toml(config), {"variants": "P-w"}, file=config)
    runs = matrix.runs()
    assert matrix.variants == (Variant.P_W,) and matrix.duration_s == 1.5
    prefix = "room_P-w_stereo_geometric"
    assert [r.run_id for r in runs[:4]] == [f"{prefix}_seed0_1.5s", f"{prefix}_seed0_1.5s_stride2", f"{prefix}_seed1_1.5s", f"{prefix}_seed1_1.5s_stride2"]
    hall = runs[-1]
    assert hall.input_name == "hall" and hall.scene == str(tmp_path / "scenes" / "hall.json")  # relative to the TOML file


@pytest.mark.parametrize(
    ("values", "words"),
    [
        ({"seeds": "x"}, ["--seeds", "'x' is not an integer"]),
        ({"seeds": "4-2"}, ["--seeds", "4-2"]),
        ({"variants": "P-wo,Q"}, ["--variants", "Q"]),
        ({"modes": "mono"}, ["--modes", "mono"]),
        ({"segmenters": "magic"}, ["--segmenters", "magic"]),
        ({"scenes": "mc-a"}, ["--scenes", "coplanar sim"]),
        ({"scenes": "nowhere.json"}, ["--scenes", "nowhere.json"]),
        ({"datasets": "/no/such/folder"}, ["--datasets", "no such file"]),
        ({"speeds": "0"}, ["--speeds", "more than 0"]),
        ({"strides": "0"}, ["--strides", "at least 1"]),
        ({"duration": "nan"}, ["--duration"]),
        ({"duration": "1,2"}, ["--duration", "one value"]),
        ({"frames": "2.5"}, ["--frames", "not an integer"]),
        ({"scenes": "room,"}, ["--scenes", "empty"]),
        ({"colour": "red"}, ["--colour", "not a sweep axis"]),
        ({"windows": "1"}, ["--windows", "1 is outside [2, 1000]"]),
        ({"keyframes": "0"}, ["--keyframes", "at least 1"]),
        ({"trajectory_frame": "imu"}, ["--trajectory-frame", "'imu' is not one of truth, camera"]),
        ({"dense": "yes"}, ["--dense", "true or false"]),
        ({"topics": "cam0"}, ["--topics", "NAME=TOPIC"]),
        ({"topics": "left=/cam0/image_raw"}, ["--topics", "'left' is not one of cam0, cam1, imu0, groundtruth"]),
        ({"topics": "cam0=image"}, ["--topics", "cam0", "not a topic name"]),
        ({"segmenter_model": "/no/model.onnx"}, ["--segmenter-model", "no such file"]),
    ],
)
def test_bad_values_name_the_option(values: dict[str, object], words: list[str]) -> None:
    with pytest.raises(MatrixError) as caught:
        matrix_from(None, values).runs()
    message = str(caught.value)
    assert "\n" not in message and all(w in message for w in words), message


def test_bad_toml_names_the_file_and_key(tmp_path: pathlib.Path) -> None:
    config = tmp_path / "sweep.toml"
    config.write_text("variants = [\n")
    with pytest.raises(MatrixError, match="sweep.toml: not TOML"):
        read_toml(config)
    config.write_text("scenes = true\n")
    with pytest.raises(MatrixError, match=r"sweep.toml: scenes: expected a list"):
        matrix_from(read_toml(config), {}, file=config)
    config.write_text("seeds = [0, -1]\n")
    with pytest.raises(MatrixError, match=r"sweep.toml: seeds: -1 is outside"):
        matrix_from(read_toml(config), {}, file=config)


def test_two_datasets_of_one_name_are_refused(tmp_path: pathlib.Path) -> None:
    for parent in ("a", "b"):
        (tmp_path / parent / "seq").mkdir(parents=True)
    with pytest.raises(MatrixError, match="share the folder seq_"):
        matrix_from(None, {"datasets": f"{tmp_path}/a/seq,{tmp_path}/b/seq"}).runs()


def test_an_axis_the_options_replace_is_not_checked_in_the_file(tmp_path: pathlib.Path) -> None:
    config = tmp_path / "sweep.toml"
    config.write_text('datasets = ["gone/MH_01"]\nvariants = "all"\n')
    (tmp_path / "here").mkdir()
    runs = matrix_from(read_toml(config), {"datasets": str(tmp_path / "here")}, file=config).runs()
    assert [r.input_name for r in runs] == ["here"] * 6
    with pytest.raises(MatrixError, match=r"sweep.toml: datasets: gone/MH_01: no such file"):
        matrix_from(read_toml(config), {}, file=config)


def test_paths_that_the_file_system_refuses_are_one_line() -> None:
    with pytest.raises(MatrixError, match="no such file"):
        matrix_from(None, {"datasets": "~nobody-of-that-name/data"}).runs()
    with pytest.raises(MatrixError, match="File name too long"):
        matrix_from(None, {"scenes": "x/" * 3000}).runs()


def test_run_options_reach_every_run_and_its_folder_name(tmp_path: pathlib.Path) -> None:
    """The options every run shares (`coplanar run`'s): windows an axis, keyframes, dense and
    the trajectory frame in the folder name; a bag's topics and the segmenter model in the
    config (and run.json), where they apply."""
    model = tmp_path / "seg.onnx"
    model.write_bytes(b"")
    shared = {"keyframes": "3", "dense": True, "trajectory_frame": "camera", "segmenter_model": str(model)}
    fields = parse_axes({"scenes": "room", "variants": "PL-w", "windows": "5,10", "segmenters": "geometric,learned", **shared})
    runs = SweepMatrix(**fields).runs()
    assert [r.run_id for r in runs] == [
        "room_PL-w_stereo_geometric_seed0_30s_window5_keyframes3_dense_camera",
        "room_PL-w_stereo_geometric_seed0_30s_keyframes3_dense_camera",
        "room_PL-w_stereo_learned_seed0_30s_window5_keyframes3_dense_camera",
        "room_PL-w_stereo_learned_seed0_30s_keyframes3_dense_camera",
    ]
    assert runs[0].sequence == "room (window 5, 3 keyframes)" and runs[1].sequence == "room (3 keyframes)"
    assert runs[0].config().window == 5 and runs[0].config().segmenter_model is None  # the model: the learned segmenter's only
    assert runs[2].config().segmenter_model == model and runs[2].parameters()["segmenter_model"] == str(model)
    # Each mode's own window unless told: VIO's is 20, so its window-10 run is named.
    vio = SweepMatrix(**parse_axes({"scenes": "room", "variants": "PL-w", "modes": "vio", "windows": "10,20"})).runs()
    assert [r.run_id for r in vio] == ["room_PL-w_vio_learned_seed0_30s_window10", "room_PL-w_vio_learned_seed0_30s"]
    (default,) = SweepMatrix(**parse_axes({"scenes": "room", "variants": "PL-w", "modes": "vio"})).runs()
    assert default.window == 20 and default.parameters()["window"] == 20 and default.config().window == 20
    (tmp_path / "V1_01.bag").write_bytes(b"")
    toml = tmp_path / "sweep.toml"
    toml.write_text('datasets = ["V1_01.bag"]\nvariants = ["P-wo"]\n[topics]\ncam0 = "/left/image"\nimu0 = "/imu"\n')
    (bag,) = matrix_from(read_toml(toml), {}, file=toml).runs()
    assert bag.config().reader.topics == (("cam0", "/left/image"), ("imu0", "/imu"))
    assert bag.parameters()["topics"] == "cam0=/left/image,imu0=/imu" and bag.run_id == "V1_01_P-wo_stereo_geometric_seed0"
    assert matrix_from(None, {"datasets": str(tmp_path / "V1_01.bag"), "topics": "imu0=/imu, cam0=/left/image"}).runs()[0].topics == bag.topics
    scene, _ = matrix_from(read_toml(toml), {"scenes": "room"}, file=toml).runs()  # the topics: the bag's only
    assert scene.scene == "room" and scene.topics == () and scene.config().reader.topics == ()
