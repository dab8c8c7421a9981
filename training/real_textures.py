"""Real photographs as textures of the segmenter's rendered training rooms (training time
only; never imported by the runtime package).

The photographs are the ones scikit-image ships inside its wheel (the folder of
`skimage.data`), read straight from that folder with OpenCV: nothing is fetched from the
network, and `skimage.data`'s other images (which it would download) are never asked for.
Two sets:

- `SURFACES`: repeating close-ups of real surfaces (brick, grass, gravel, the moon's
  craters), tiled with mirrored copies (no seams) at a random scale: walls, floors, boxes.
- `PICTURES`: photographs and scanned pages, stretched over the whole rectangle: posters
  and other decals on the walls and the floor.

`register_photo_textures()` makes each a texture kind of the renderer
(`backend.data.textures.register_texture`), named `photo-NAME`, for this process.
"""

from __future__ import annotations

import functools
import pathlib

import cv2
import numpy as np

SURFACES = ("brick", "grass", "gravel", "moon")
PICTURES = ("camera", "astronaut", "coffee", "chelsea", "page", "text", "rocket", "motorcycle_left", "coins", "hubble_deep_field")
PREFIX = "photo-"


def data_folder() -> pathlib.Path:
    """The folder of the photographs inside the installed scikit-image (needs the `train`
    extra); its location only: the package's download machinery is not used."""
    import skimage.data

    return pathlib.Path(skimage.data.__file__).resolve().parent


@functools.lru_cache(maxsize=32)
def photo(name: str) -> np.ndarray:
    """The bundled photograph `name` (its file name without the extension) as a grey uint8
    image (read-only). Raises FileNotFoundError when the wheel does not hold it."""
    files = sorted(p for p in data_folder().glob(f"{name}.*") if p.suffix.lower() in (".png", ".jpg"))
    image = cv2.imread(str(files[0]), cv2.IMREAD_GRAYSCALE) if files else None
    if image is None:
        raise FileNotFoundError(f"scikit-image ships no photograph {name!r} in {data_folder()}")
    image.setflags(write=False)
    return image


def _contrast(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Random contrast (0.6–1.3 about the mean) and brightness (±40 grey levels), uint8."""
    x = image.astype(np.float32)
    mean = float(x.mean())
    x = (x - mean) * rng.uniform(0.6, 1.3) + mean + rng.uniform(-40.0, 40.0)
    return np.clip(x, 0, 255).astype(np.uint8)


def surface_texture(name: str, rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """The surface photograph `name` tiled over `shape` (rows, cols): turned by a random
    multiple of 90°, scaled to 96–512 texels a tile, mirrored copies side by side."""
    tile = np.rot90(photo(name), int(rng.integers(4)))
    side = int(rng.integers(96, 513))
    tile = cv2.resize(np.ascontiguousarray(tile), (side, side), interpolation=cv2.INTER_AREA)
    pair = np.concatenate([tile, tile[:, ::-1]], axis=1)
    pair = np.concatenate([pair, pair[::-1]], axis=0)
    rows, cols = shape
    reps = (rows // pair.shape[0] + 2, cols // pair.shape[1] + 2)
    y0, x0 = int(rng.integers(pair.shape[0])), int(rng.integers(pair.shape[1]))
    return _contrast(np.tile(pair, reps)[y0 : y0 + rows, x0 : x0 + cols], rng)


def picture_texture(name: str, rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """The photograph `name` (maybe mirrored) stretched over `shape` (rows, cols)."""
    image = photo(name)
    if rng.random() < 0.5:
        image = image[:, ::-1]
    rows, cols = shape
    return _contrast(cv2.resize(np.ascontiguousarray(image), (cols, rows), interpolation=cv2.INTER_AREA), rng)


def surface_kinds() -> tuple[str, ...]:
    """Texture kinds of the surface photographs (registered by `register_photo_textures`)."""
    return tuple(PREFIX + n for n in SURFACES)


def picture_kinds() -> tuple[str, ...]:
    """Texture kinds of the pictures (registered by `register_photo_textures`)."""
    return tuple(PREFIX + n for n in PICTURES)


def register_photo_textures() -> tuple[str, ...]:
    """Registers every photograph as the renderer's texture kind `photo-NAME` (this process
    only) and returns the kinds; loads each once, so a missing file fails here."""
    from backend.data.textures import register_texture

    for name in SURFACES:
        photo(name)
        register_texture(PREFIX + name, functools.partial(surface_texture, name))
    for name in PICTURES:
        photo(name)
        register_texture(PREFIX + name, functools.partial(picture_texture, name))
    return surface_kinds() + picture_kinds()
