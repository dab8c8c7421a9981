"""Real photographs as training textures (no torch needed): they come from the installed
scikit-image's own folder, offline, and the rendered rooms wear them."""

from __future__ import annotations

import pathlib
import socket
import sys

import numpy as np
import pytest

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "training"))

pytest.importorskip("skimage")

import real_textures
from photometric import Photometric, augment
from planeseg_data import INPUT_H, INPUT_W, random_room, rendered_samples


@pytest.fixture
def no_network(monkeypatch: pytest.MonkeyPatch) -> None:
    """Any attempt to open a socket fails the test."""

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the texture loader tried to reach the network")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)


def test_every_photograph_loads_offline_from_the_package(no_network: None) -> None:
    real_textures.photo.cache_clear()
    for name in real_textures.SURFACES + real_textures.PICTURES:
        image = real_textures.photo(name)
        assert image.dtype == np.uint8 and image.ndim == 2 and min(image.shape) >= 128
        assert image.std() > 10  # a photograph, not a blank
    with pytest.raises(FileNotFoundError):
        real_textures.photo("no_such_photo")


def test_photo_textures_fill_any_shape_and_are_registered(no_network: None) -> None:
    from backend.data.textures import known_kinds, texture_image

    kinds = real_textures.register_photo_textures()
    assert set(kinds) <= set(known_kinds())
    for kind in (real_textures.PREFIX + "brick", real_textures.PREFIX + "camera"):
        a = texture_image(kind, 3, 700, 1300)
        assert a.shape == (700, 1300) and a.dtype == np.uint8
        np.testing.assert_array_equal(a, texture_image.__wrapped__(kind, 3, 700, 1300))  # deterministic per seed


def test_rendered_samples_wear_real_photographs(no_network: None) -> None:
    """With photos=1 every textured surface of a layout is a photograph; at 0 the layouts are
    the procedural ones, drawn exactly as before (the held-out rooms stay the same)."""
    real_textures.register_photo_textures()
    rng = np.random.default_rng(4)
    scene = random_room(rng, "photos", photos=1.0)
    assert all(r.texture.kind.startswith(real_textures.PREFIX) for r in scene.rectangles)
    plain_a = random_room(np.random.default_rng(4), "a")
    plain_b = random_room(np.random.default_rng(4), "b", photos=0.0)
    assert [r.texture for r in plain_a.rectangles] == [r.texture for r in plain_b.rectangles]
    assert not any(r.texture.kind.startswith(real_textures.PREFIX) for r in plain_a.rectangles)
    samples = rendered_samples(7, layouts=2, views_per_layout=2, photos=1.0)
    plain = rendered_samples(7, layouts=2, views_per_layout=2)
    assert len(samples) == 4 and all(s.image.shape == (INPUT_H, INPUT_W) for s in samples)
    assert any(not np.array_equal(s.image, t.image) for s, t in zip(samples, plain))
    assert all(np.any(s.labels >= 0) for s in samples)  # exact plane ids, whatever the texture


def test_photometric_augmentation_keeps_the_range_and_is_reproducible() -> None:
    x = np.random.default_rng(0).uniform(0, 1, (3, INPUT_H, INPUT_W)).astype(np.float32)
    a = augment(x, np.random.default_rng(1), Photometric())
    b = augment(x, np.random.default_rng(1), Photometric())
    np.testing.assert_array_equal(a, b)
    assert a.shape == x.shape and a.dtype == np.float32 and a.min() >= 0 and a.max() <= 1
    assert not np.allclose(a, x)
    off = augment(x, np.random.default_rng(1), Photometric(gamma=0, blur_px=0, noise=0, vignette=0))
    np.testing.assert_array_equal(off, x)
