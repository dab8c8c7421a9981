"""The data-source protocols and the reader registry (backend/data/source.py)."""

from __future__ import annotations

import pathlib
import typing

import numpy as np
import pytest

from backend.data.errors import DatasetError
from backend.data.scenes import builtin_scene, scene_to_json
from backend.data.source import DATASET_FORMATS, EUROC_FORMAT, GroundTruthSamples, RenderedTruth, StereoSource, dataset_format, open_dataset
from backend.data.synthetic import SequenceSettings, SyntheticSequence, render_sequence

SHARED = pathlib.Path(__file__).resolve().parents[3].parent / "shared" / "data"


@pytest.fixture(scope="module")
def euroc(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    root = tmp_path_factory.mktemp("euroc")
    render_sequence(builtin_scene("room"), root, settings=SequenceSettings(duration_s=0.2))
    return root


def test_a_euroc_folder_is_recognized_and_is_a_stereo_source_with_an_imu(euroc: pathlib.Path) -> None:
    for path in (euroc, euroc / "mav0"):
        source = open_dataset(path)
        assert type(source).__name__ == "EurocDataset" and len(source) == 5
        assert isinstance(source, StereoSource) and not isinstance(source, RenderedTruth)
        assert source.imu_noise is not None and source.T_body_rect0.shape == (4, 4)  # type: ignore[attr-defined]
        assert source.imu_label.endswith("mav0/imu0/data.csv")  # type: ignore[attr-defined]


def test_a_scene_file_is_rendered_on_demand_with_its_truth(tmp_path: pathlib.Path) -> None:
    path = tmp_path / "boxes.json"
    path.write_text(scene_to_json(builtin_scene("boxes")))
    source = open_dataset(path)
    assert isinstance(source, SyntheticSequence) and isinstance(source, StereoSource) and isinstance(source, RenderedTruth)
    left, right = source.rectified_pair(0)
    assert left.dtype == np.uint8 and left.shape == right.shape
    np.testing.assert_array_equal(source.T_body_rect0, source.T_body_cam0)


@pytest.mark.parametrize(
    ("make", "words"),
    [
        (lambda p: p / "missing", "no such folder"),
        (lambda p: p, "no mav0 folder"),
        (lambda p: (p / "broken.json").write_text("{") and p / "broken.json", "invalid JSON"),
    ],
)
def test_what_no_reader_recognizes_is_one_line_naming_it(tmp_path: pathlib.Path, make, words: str) -> None:
    path = make(tmp_path)
    with pytest.raises(DatasetError) as error:
        open_dataset(path)
    assert words in str(error.value) and str(path) in str(error.value) and "\n" not in str(error.value)


def test_every_format_is_named_and_tumvi_is_asked_before_euroc() -> None:
    """A TUM-VI export holds mav0 too: its reader must be asked first. EuRoC's reader is the
    fallback that says what is missing when no format recognizes a path."""
    names = [f.name for f in DATASET_FORMATS]
    assert all(names) and names.index(EUROC_FORMAT.name) == next(i for i, n in enumerate(names) if n.startswith("TUM-VI")) + 1
    assert EUROC_FORMAT.name.startswith("EuRoC") and dataset_format("/no/such/path") is EUROC_FORMAT


@pytest.mark.skipif(not (SHARED / "euroc_mh01_slice").exists(), reason="../shared/data is absent")
def test_the_real_mh01_slice_opens_as_euroc_without_an_imu() -> None:
    source = open_dataset(SHARED / "euroc_mh01_slice")
    assert isinstance(source, StereoSource) and len(source) == 300 and not source.has_imu  # type: ignore[attr-defined]
    # isinstance asks for every protocol member in no fixed order: none may raise here.
    for protocol in (StereoSource, GroundTruthSamples, RenderedTruth):
        for name in protocol.__protocol_attrs__ if hasattr(protocol, "__protocol_attrs__") else typing._get_protocol_attrs(protocol):  # type: ignore[attr-defined]
            hasattr(source, name)
    assert not isinstance(source, RenderedTruth)
    with pytest.raises(DatasetError, match="imu0"):
        source.imu_noise  # type: ignore[attr-defined]  # noqa: B018


def test_a_rendered_sequence_has_the_truth_a_folder_lacks() -> None:
    seq = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=0.2))
    assert isinstance(seq, RenderedTruth) and seq.imu_label == "IMU"


def test_each_source_says_which_frame_its_ground_truth_is_of(euroc: pathlib.Path) -> None:
    """EuRoC folders and rendered scenes give body (IMU) poses: `T_truth_rect0` is the left
    camera in the body, and `T_world_rect0 · T_truth_rect0⁻¹` the body's ground truth."""
    folder = open_dataset(euroc)
    rendered = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=0.2))
    for source in (folder, rendered):
        assert source.ground_truth_frame == "body"
        np.testing.assert_allclose(source.T_truth_rect0, source.T_body_rect0, atol=1e-15)  # type: ignore[attr-defined]
        np.testing.assert_allclose(source.T_world_rect0 @ np.linalg.inv(source.T_truth_rect0), source.T_world_body, atol=1e-12)  # type: ignore[attr-defined]
    # The folder's ground-truth file, sample by sample: the rendered body poses at the IMU
    # rate and at the last frame (past the last IMU sample), so every frame has its own row.
    assert isinstance(folder, GroundTruthSamples) and not isinstance(rendered, GroundTruthSamples)
    stamps, T_world_body = folder.ground_truth_samples()
    np.testing.assert_array_equal(stamps, np.append(rendered.imu.timestamp_ns, rendered.timestamps_ns[-1]))
    assert folder.ground_truth_valid.all()
    at_frames = np.searchsorted(stamps, rendered.timestamps_ns)
    np.testing.assert_allclose(T_world_body[at_frames], rendered.T_world_body, atol=1e-6)


def test_a_folder_without_ground_truth_has_no_samples(euroc: pathlib.Path, tmp_path: pathlib.Path) -> None:
    import shutil

    copy = tmp_path / "no_truth"
    shutil.copytree(euroc, copy)
    shutil.rmtree(copy / "mav0" / "state_groundtruth_estimate0")
    source = open_dataset(copy)
    stamps, T = source.ground_truth_samples()  # type: ignore[attr-defined]
    assert stamps.shape == (0,) and T.shape == (0, 4, 4) and source.ground_truth_frame == "body"
