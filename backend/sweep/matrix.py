"""A sweep's matrix: the axes `coplanar sweep` varies (inputs, variants, modes, segmenters,
seeds, speeds, strides, windows) and the runs they span, one :class:`RunSpec` each, with the
options every run shares (`coplanar run`'s: duration, frames, keyframes, dense, trajectory
frame, a dataset's calibration and topics, the learned segmenter's model).

The axes come from the command line (comma lists as text: `--seeds 0-4`, `--variants
P-wo,PL-w`) or from a TOML file (the same names as keys, lists or the same text), through one
parser, :func:`parse_axes`; a bad value is a :class:`MatrixError` naming the option or key.
Speeds, strides and the duration apply to rendered scenes only (a dataset is run as
recorded, as `coplanar run` does). The Monte-Carlo worlds are `coplanar sim`'s, not a sweep's.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import pathlib
import re
import tomllib
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from backend.data.topics import TOPIC_NAMES
from backend.optim.variant import VARIANTS, Variant
from backend.pipeline.factory import default_window

if TYPE_CHECKING:
    from backend.pipeline.factory import EngineConfig

MODES = ("stereo", "vio")
SEGMENTERS = ("geometric", "learned", "oracle")
DEFAULT_SEGMENTER = {"stereo": "geometric", "vio": "learned"}  # as backend.pipeline.factory
DEFAULT_DURATION_S = 30.0  # as `coplanar run`
MAX_DURATION_S = 3600.0  # as `coplanar run` (app/sources.py)
MAX_SPEED = 10.0
MAX_WINDOW = 1000
MAX_RUNS = 100_000
TRAJECTORY_FRAMES = ("truth", "camera")  # as `coplanar run --trajectory-frame`
AXES = (
    "scenes",
    "datasets",
    "variants",
    "modes",
    "segmenters",
    "seeds",
    "speeds",
    "strides",
    "windows",
    "duration",
    "frames",
    "keyframes",
    "dense",
    "trajectory_frame",
    "calib",
    "topics",
    "segmenter_model",
)


class MatrixError(ValueError):
    """A bad axis value: one line naming the option (or the TOML key)."""


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One run of a sweep: its input (a rendered `scene`, a built-in name or a scene file, or
    a `dataset` path, absolute), `variant`, `mode` (stereo | vio), `segmenter` (geometric |
    learned | oracle; resolved, never the mode's implicit default), `seed`, and for rendered
    scenes `duration_s` (seconds of motion), `speed` (times the scene's speed) and `stride`
    (every N-th frame); `window`: keyframes optimized per step (None: the mode's); `frames`: only the first N
    frames (None: all); `keyframes`: stop after N keyframes (None: at the end); `dense`: also
    fuse the keyframes' depth (mesh.ply); `trajectory_frame`: truth | camera; `calib`: the
    calibration a dataset that holds none is read with (a ROS bag's `--calib`; None: none);
    `topics`: (name, topic) pairs a bag is read with; `segmenter_model`: the learned
    segmenter's model file (None: the shipped one). As `coplanar run`'s options of those names."""

    scene: str | None
    dataset: str | None
    variant: Variant
    mode: str
    segmenter: str
    seed: int
    duration_s: float | None = None
    speed: float = 1.0
    stride: int = 1
    frames: int | None = None
    calib: str | None = None
    window: int | None = None  # None: the mode's (`coplanar run --window`'s default)
    keyframes: int | None = None
    dense: bool = False
    trajectory_frame: str = "truth"
    topics: tuple[tuple[str, str], ...] = ()
    segmenter_model: str | None = None

    def __post_init__(self) -> None:
        if self.window is None:
            object.__setattr__(self, "window", default_window(self.mode))

    @property
    def input_name(self) -> str:
        """The input as the tables name it: a built-in scene's name, a scene file's or a
        dataset folder's name (the folder above `mav0` for a `mav0` path)."""
        if self.scene is not None:
            path = pathlib.Path(self.scene)
            return path.stem if path.suffix == ".json" else self.scene
        path = pathlib.Path(str(self.dataset))
        return path.parent.name if path.name == "mav0" else path.stem if path.is_file() else path.name

    @property
    def sequence(self) -> str:
        """The input with what changes its frames or their estimate besides the variant
        (speed, stride, window, frame and keyframe limits): a row of the results table."""
        extra = [
            f"×{self.speed:g} speed" if self.speed != 1.0 else "",
            f"stride {self.stride}" if self.stride != 1 else "",
            f"window {self.window}" if self.window != default_window(self.mode) else "",
            f"{self.frames} frames" if self.frames is not None else "",
            f"{self.keyframes} keyframes" if self.keyframes is not None else "",
        ]
        extra = [e for e in extra if e]
        return f"{self.input_name} ({', '.join(extra)})" if extra else self.input_name

    @property
    def run_id(self) -> str:
        """The run's folder name, from its parameters: `INPUT_VARIANT_MODE_SEGMENTER_seedN`,
        then for a rendered scene its duration (`30s`), and `speedF`, `strideN`, `windowN`,
        `framesN`, `keyframesN`, `dense`, `camera` (the trajectory frame) where not the
        default. The same parameters give the same name in every sweep (resume); the
        calibration, topics and segmenter model are not in it but in run.json, which resume
        compares."""
        parts = [self.input_name, str(self.variant), self.mode, self.segmenter, f"seed{self.seed}"]
        if self.duration_s is not None:
            parts.append(f"{self.duration_s:g}s")
        if self.speed != 1.0:
            parts.append(f"speed{self.speed:g}")
        if self.stride != 1:
            parts.append(f"stride{self.stride}")
        if self.window != default_window(self.mode):
            parts.append(f"window{self.window}")
        if self.frames is not None:
            parts.append(f"frames{self.frames}")
        if self.keyframes is not None:
            parts.append(f"keyframes{self.keyframes}")
        if self.dense:
            parts.append("dense")
        if self.trajectory_frame != "truth":
            parts.append(self.trajectory_frame)
        return re.sub(r"[^A-Za-z0-9._+-]", "-", "_".join(parts))

    def parameters(self) -> dict[str, Any]:
        """The parameters as a results row and run.json hold them (JSON values)."""
        return {
            "run_id": self.run_id,
            "input": self.input_name,
            "sequence": self.sequence,
            "input_kind": "scene" if self.scene is not None else "dataset",
            "input_path": self.scene if self.scene is not None else self.dataset,
            "variant": str(self.variant),
            "mode": self.mode,
            "segmenter": self.segmenter,
            "seed": self.seed,
            "duration_s": self.duration_s,
            "speed": self.speed,
            "stride": self.stride,
            "frames_limit": self.frames,
            "calib": self.calib,
            "window": self.window,
            "keyframes_limit": self.keyframes,
            "dense": self.dense,
            "trajectory_frame": self.trajectory_frame,
            "topics": ",".join(f"{name}={topic}" for name, topic in self.topics) or None,
            "segmenter_model": self.segmenter_model,
        }

    def config(self) -> EngineConfig:
        """The headless engine's config (as `coplanar run` builds it for the same options)."""
        from backend.pipeline.factory import EngineConfig

        if self.scene is not None:
            options: dict[str, Any] = {"scene": self.scene, "duration_s": self.duration_s or DEFAULT_DURATION_S, "speed": self.speed, "stride": self.stride}
        else:
            from backend.data.source import ReaderOptions

            options = {"dataset": self.dataset, "reader": ReaderOptions(calib=None if self.calib is None else pathlib.Path(self.calib), topics=self.topics)}
        model = None if self.segmenter_model is None else pathlib.Path(self.segmenter_model)
        return EngineConfig(
            **options,
            frames=self.frames,
            seed=self.seed,
            variant=self.variant,
            window=self.window,
            mode=self.mode,  # type: ignore[arg-type]
            segmenter=self.segmenter,  # type: ignore[arg-type]
            segmenter_model=model,
        )


@dataclasses.dataclass(frozen=True)
class SweepMatrix:
    """The axes of a sweep (module docstring); :meth:`runs` spans them. `segmenters` None:
    each mode's default. No `scenes` and no `datasets`: the standard scenes (`STANDARD_SCENES`: room, corridor, boxes)."""

    scenes: tuple[str, ...] = ()
    datasets: tuple[str, ...] = ()
    variants: tuple[Variant, ...] = VARIANTS
    modes: tuple[str, ...] = ("stereo",)
    segmenters: tuple[str, ...] | None = None
    seeds: tuple[int, ...] = (0,)
    speeds: tuple[float, ...] = (1.0,)
    strides: tuple[int, ...] = (1,)
    windows: tuple[int | None, ...] = (None,)
    duration_s: float = DEFAULT_DURATION_S
    frames: int | None = None
    keyframes: int | None = None
    dense: bool = False
    trajectory_frame: str = "truth"
    calib: str | None = None
    topics: tuple[tuple[str, str], ...] = ()
    segmenter_model: str | None = None

    def runs(self) -> list[RunSpec]:
        """Every run, inputs outermost (scenes, then datasets), then seeds, modes,
        segmenters, speeds, strides, windows and variants innermost; MatrixError for two runs with
        one folder name (two datasets of one folder name) or more than MAX_RUNS runs."""
        from backend.data.scenes import STANDARD_SCENES

        scenes = self.scenes or (() if self.datasets else STANDARD_SCENES)
        inputs: list[tuple[str | None, str | None]] = [(s, None) for s in scenes] + [(None, d) for d in self.datasets]
        shared = {"frames": self.frames, "keyframes": self.keyframes, "dense": self.dense, "trajectory_frame": self.trajectory_frame}
        runs = []
        for (scene, dataset), seed, mode in itertools.product(inputs, self.seeds, self.modes):
            segmenters = self.segmenters or (DEFAULT_SEGMENTER[mode],)
            motions = itertools.product(self.speeds, self.strides) if scene is not None else [(1.0, 1)]
            for segmenter, (speed, stride), window, variant in itertools.product(segmenters, list(motions), self.windows, self.variants):
                duration = self.duration_s if scene is not None else None
                reading = {"calib": self.calib, "topics": self.topics} if dataset is not None else {}
                model = {"segmenter_model": self.segmenter_model} if segmenter == "learned" else {}
                runs.append(RunSpec(scene, dataset, variant, mode, segmenter, seed, duration_s=duration, speed=speed, stride=stride, window=window, **shared, **reading, **model))  # type: ignore[arg-type]
                if len(runs) > MAX_RUNS:
                    raise MatrixError(f"more than {MAX_RUNS} runs: split the sweep")
        seen: dict[str, RunSpec] = {}
        for run in runs:
            other = seen.setdefault(run.run_id, run)
            if other is not run:
                raise MatrixError(f"two runs would share the folder {run.run_id}: {_input_path(other)} and {_input_path(run)} (give the datasets folders of different names)")
        return runs


def _input_path(spec: RunSpec) -> str:
    return str(spec.scene if spec.scene is not None else spec.dataset)


def parse_axes(values: Mapping[str, object], *, where: str = "--", base: pathlib.Path | None = None) -> dict[str, Any]:
    """The axes in `values` (names of AXES; each a comma list as text, a TOML list or a
    scalar) checked and converted to SweepMatrix's fields. `where` prefixes the name in
    messages (`--` for options, `FILE: ` for a TOML file); relative scene files and datasets
    are taken from `base` (the TOML file's folder; None: the working folder)."""
    fields: dict[str, Any] = {}
    for key, value in values.items():
        if key not in AXES:
            raise MatrixError(f"{where}{key}: not a sweep axis (expected {', '.join(AXES)})")
        name = f"{where}{key.replace('_', '-') if where == '--' else key}"
        if key == "dense":
            fields["dense"] = _flag(value, name)
            continue
        if key == "topics":
            fields["topics"] = _topics(value, name)
            continue
        items = _items(value, name)
        if key == "scenes":
            fields["scenes"] = tuple(_scene(s, name, base) for s in items)
        elif key == "datasets":
            fields["datasets"] = tuple(_dataset(d, name, base) for d in items)
        elif key == "variants":
            fields["variants"] = _variants(items, name)
        elif key == "modes":
            fields["modes"] = tuple(_choice(m, name, MODES) for m in _unique(items))
        elif key == "segmenters":
            fields["segmenters"] = tuple(_choice(s, name, SEGMENTERS) for s in _unique(items))
        elif key == "seeds":
            fields["seeds"] = tuple(_unique([seed for item in items for seed in _seed_range(item, name)]))
        elif key == "speeds":
            fields["speeds"] = tuple(_unique([_number(s, name, low=0.0, high=MAX_SPEED) for s in items]))
        elif key == "strides":
            fields["strides"] = tuple(_unique([_integer(s, name, low=1) for s in items]))
        elif key == "windows":
            fields["windows"] = tuple(_unique([_integer(w, name, low=2, high=MAX_WINDOW) for w in items]))
        elif key == "keyframes":
            fields["keyframes"] = _integer(_single(items, name), name, low=1)
        elif key == "trajectory_frame":
            fields["trajectory_frame"] = _choice(_single(items, name), name, TRAJECTORY_FRAMES)
        elif key == "segmenter_model":
            fields["segmenter_model"] = _model(_single(items, name), name, base)
        elif key == "duration":
            fields["duration_s"] = _number(_single(items, name), name, low=0.0, high=MAX_DURATION_S, unit=" seconds")
        elif key == "frames":
            fields["frames"] = _integer(_single(items, name), name, low=1)
        elif key == "calib":
            fields["calib"] = _dataset(_single(items, name), name, base)
    return fields


def matrix_from(file_values: Mapping[str, object] | None, option_values: Mapping[str, object], *, file: pathlib.Path | None = None) -> SweepMatrix:
    """The matrix of a TOML file's axes (`file_values`, from `file`) with the command line's
    (`option_values`, those given) taking their place where both name an axis."""
    fields: dict[str, Any] = {}
    if file_values is not None:
        kept = {key: value for key, value in file_values.items() if key not in option_values}  # not checked: replaced
        fields.update(parse_axes(kept, where=f"{file}: ", base=None if file is None else file.parent))
    fields.update(parse_axes(option_values))
    return SweepMatrix(**fields)


def read_toml(path: pathlib.Path) -> dict[str, object]:
    """A sweep's TOML file: its top-level keys (MatrixError, naming the file, when it cannot be
    read or is not TOML)."""
    from backend.data.errors import DatasetError, read_text

    try:
        text = read_text(path)  # a regular file only: a FIFO would block
    except DatasetError as e:
        raise MatrixError(f"{path}: cannot read it: {e.reason}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise MatrixError(f"{path}: not TOML: {e}") from None


def _items(value: object, name: str) -> list[object]:
    """A comma list as text, a list, or one scalar, as its items (none empty)."""
    if isinstance(value, str):
        items: list[object] = [v.strip() for v in value.split(",")]
    elif isinstance(value, list):
        items = list(value)
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        items = [value]
    else:
        raise MatrixError(f"{name}: expected a list or comma-separated text, not {type(value).__name__}")
    if not items or any(item == "" for item in items):
        raise MatrixError(f"{name}: an empty entry")
    for item in items:
        if not isinstance(item, (str, int, float)):
            raise MatrixError(f"{name}: {type(item).__name__} {item!r} inside the list: expected text or numbers")
    return items


def _flag(value: object, name: str) -> bool:
    """true / false (TOML), or the text `true` / `false`."""
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.strip().lower() in ("true", "false"):
        return value.strip().lower() == "true"
    raise MatrixError(f"{name}: {value!r}: expected true or false")


def _topics(value: object, name: str) -> tuple[tuple[str, str], ...]:
    """Topic overrides: a TOML table {cam0 = "/left"}, or `NAME=TOPIC` items (a list or comma
    text); names of TOPIC_NAMES, topics starting with `/`."""
    if isinstance(value, dict):
        pairs = [(str(k), v) for k, v in value.items()]
    else:
        pairs = []
        for item in _items(value, name):
            key, sep, topic = _text(item, name).partition("=")
            if not sep:
                raise MatrixError(f"{name}: {item!r}: expected NAME=TOPIC")
            pairs.append((key.strip(), topic.strip()))
    checked: dict[str, str] = {}
    for key, topic in pairs:
        if key not in TOPIC_NAMES:
            raise MatrixError(f"{name}: {key!r} is not one of {', '.join(TOPIC_NAMES)}")
        if not isinstance(topic, str) or not topic.startswith("/") or "\x00" in topic:
            raise MatrixError(f"{name}: {key}: {topic!r} is not a topic name (/...)")
        checked[key] = topic
    return tuple(sorted(checked.items()))


def _model(item: object, name: str, base: pathlib.Path | None) -> str:
    """An existing model file (as an absolute path)."""
    return _existing(item, name, base, file=True)


def _unique(items: Sequence[Any]) -> list[Any]:
    return list(dict.fromkeys(items))


def _single(items: list[object], name: str) -> object:
    if len(items) != 1:
        raise MatrixError(f"{name}: one value, not {len(items)}")
    return items[0]


def _text(item: object, name: str) -> str:
    if not isinstance(item, str):
        raise MatrixError(f"{name}: {item!r} is not text")
    if "\x00" in item:
        raise MatrixError(f"{name}: a NUL character")
    return item


def _choice(item: object, name: str, choices: tuple[str, ...]) -> str:
    text = _text(item, name)
    if text not in choices:
        raise MatrixError(f"{name}: {text!r} is not one of {', '.join(choices)}")
    return text


def _scene(item: object, name: str, base: pathlib.Path | None) -> str:
    """A built-in scene's name, or an existing scene file (as an absolute path)."""
    from backend.data.scenes import SCENE_NAMES

    text = _text(item, name)
    if text in SCENE_NAMES:
        return text
    if text in ("mc-a", "mc-b"):
        raise MatrixError(f"{name}: {text} is a Monte-Carlo world (no images): `coplanar sim` runs those")
    path = _resolve(text, base)
    if not _is(path, name, text, file=True):
        raise MatrixError(f"{name}: {text}: neither a built-in scene ({', '.join(SCENE_NAMES)}) nor an existing scene file")
    return str(path)


def _dataset(item: object, name: str, base: pathlib.Path | None) -> str:
    """An existing path (as an absolute path); whether it is a dataset is the run's to find."""
    return _existing(item, name, base, file=False)


def _existing(item: object, name: str, base: pathlib.Path | None, *, file: bool) -> str:
    """An existing file (`file`) or path, taken from `base`, as an absolute path."""
    text = _text(item, name)
    path = _resolve(text, base)
    if not _is(path, name, text, file=file):
        raise MatrixError(f"{name}: {text}: no such file" + ("" if file else " or folder"))
    return str(path)


def _is(path: pathlib.Path, name: str, text: str, *, file: bool) -> bool:
    """Whether `path` is a file (`file`) or exists; MatrixError where the file system refuses
    the name (too long, ...)."""
    try:
        return path.is_file() if file else path.exists()
    except OSError as e:
        raise MatrixError(f"{name}: {text[:80]}{'...' if len(text) > 80 else ''}: {e.strerror or e}") from None


def _resolve(text: str, base: pathlib.Path | None) -> pathlib.Path:
    path = pathlib.Path(text)
    try:
        path = path.expanduser()
    except RuntimeError:  # `~name` of no user: a plain name then
        pass
    if not path.is_absolute() and base is not None:
        path = base / path
    return path.absolute()


def _variants(items: list[object], name: str) -> tuple[Variant, ...]:
    names = [_text(item, name) for item in items]
    if names == ["all"]:
        return VARIANTS
    bad = [n for n in names if n not in VARIANTS]
    if bad:
        raise MatrixError(f"{name}: unknown variant(s) {', '.join(bad)}; expected 'all' or some of {', '.join(VARIANTS)}")
    return tuple(Variant.parse(n) for n in _unique(names))


def _seed_range(item: object, name: str) -> list[int]:
    """`N` or `A-B` (both ends included) as seeds."""
    if isinstance(item, str) and re.fullmatch(r"\s*\d+\s*-\s*\d+\s*", item):
        low, high = (int(part) for part in item.split("-"))
        if high < low or high - low >= MAX_RUNS:
            raise MatrixError(f"{name}: {item}: a range from low to high (at most {MAX_RUNS} seeds)")
        return list(range(low, high + 1))
    return [_integer(item, name, low=0, high=2**63 - 1)]


def _integer(item: object, name: str, *, low: int, high: int | None = None) -> int:
    if isinstance(item, bool):
        raise MatrixError(f"{name}: {item!r} is not an integer")
    try:
        value = int(item) if isinstance(item, (int, str)) else None
    except ValueError:
        value = None
    if value is None:
        raise MatrixError(f"{name}: {item!r} is not an integer")
    if value < low or (high is not None and value > high):
        raise MatrixError(f"{name}: {value} is not at least {low}" if high is None else f"{name}: {value} is outside [{low}, {high}]")
    return value


def _number(item: object, name: str, *, low: float, high: float, unit: str = "") -> float:
    """A finite number in (low, high]."""
    if isinstance(item, bool):
        raise MatrixError(f"{name}: {item!r} is not a number")
    try:
        value = float(item) if isinstance(item, (int, float, str)) else math.nan
    except ValueError:
        raise MatrixError(f"{name}: {item!r} is not a number") from None
    if not (math.isfinite(value) and low < value <= high):
        raise MatrixError(f"{name}: {item} must be more than {low:g} and at most {high:g}{unit}")
    return value
