import cv2
import numpy as np
import pytest

from pcreg import InputError, image_cloud, load_image
from pcreg.registration.clouds import cloud_pyramid
from pcreg.registration.clouds import as_rgb_uint8, valid_region


def square(h=120, w=160, *, angle=0.0):
    img = np.zeros((h, w, 3), np.uint8) + 40
    cv2.rectangle(img, (50, 30), (110, 90), (200, 180, 60), -1)
    if angle:
        M = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), angle, 1.0)
        img = cv2.warpAffine(img, M, (w, h), borderValue=(40, 40, 40))
    return img


def test_canny_points_lie_on_the_square_edges_subpixel():
    # A blurred vertical step at x = 79.5 (between pixels 79 and 80): sub-pixel edges sit there.
    img = np.zeros((60, 160, 3), np.uint8)
    img[:, 80:] = 200
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    c = image_cloud(img, sampler="canny", mask=None)
    assert len(c) > 30
    np.testing.assert_allclose(np.median(c.points[:, 0]), 79.5, atol=0.05)
    # normals point along +x (the gradient direction)
    assert np.all(np.abs(c.normals[:, 0]) > 0.99)


@pytest.mark.parametrize("sampler", ["canny", "gradient", "grid"])
def test_samplers_and_colours(sampler):
    c = image_cloud(square(), sampler=sampler, top_k=500, grid_step=10)
    assert c.points.dtype == np.float64 and c.points.shape[1] == 2
    assert c.colors.shape == (len(c), 3) and c.colors.dtype == np.float32
    assert 0.0 <= c.colors.min() and c.colors.max() <= 1.0
    if sampler == "grid":
        assert len(c) == len(range(5, 119, 10)) * len(range(5, 159, 10))


def test_max_points_is_deterministic_and_bounded():
    a = image_cloud(square(), max_points=50, seed=3)
    b = image_cloud(square(), max_points=50, seed=3)
    assert len(a) == 50
    np.testing.assert_array_equal(a.points, b.points)


def test_pyramid_points_are_in_full_resolution_coordinates():
    levels = cloud_pyramid(square(240, 320), levels=3)
    assert [c.level for c in levels] == [0, 1, 2]
    for c in levels:
        # every level sees the same square: its edge points span the same full-resolution box
        assert c.points[:, 0].min() == pytest.approx(49.5, abs=2.5 * 2**c.level)
        assert c.points[:, 0].max() == pytest.approx(110.5, abs=2.5 * 2**c.level)
    assert len(levels[0]) > len(levels[1]) > len(levels[2])


def test_inputs_are_not_modified():
    img = square()
    before = img.copy()
    image_cloud(img)
    np.testing.assert_array_equal(img, before)


def test_black_padding_gives_no_points():
    img = square(angle=30.0)
    padded = cv2.warpAffine(img, np.float64([[1, 0, 25], [0, 1, 0]]), (160, 120))  # black band on the left
    mask = valid_region(padded)
    assert not mask[:, :20].any() and mask[:, 30:].all()
    c = image_cloud(padded)
    assert c.points[:, 0].min() > 27  # the band's straight edge at x = 25 is not a point


def test_formats_gray_16bit_float():
    g = square()[:, :, 0]
    assert as_rgb_uint8(g).shape == (120, 160, 3)
    assert as_rgb_uint8(g.astype(np.uint16) * 257).max() == g.max()
    assert as_rgb_uint8(g / 255.0).max() == g.max()


@pytest.mark.parametrize("bad, message", [
    (np.zeros((0, 5, 3), np.uint8), "empty image"),
    (np.zeros((4, 4, 3), np.uint8), "too small"),
    (np.zeros((10, 10, 5), np.uint8), "expected an"),
    (np.full((10, 10, 3), np.nan), "NaN"),
    ("not an array", "numpy array"),
])
def test_bad_arrays(bad, message):
    with pytest.raises(InputError, match=message):
        as_rgb_uint8(bad)


def test_load_image_errors(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        load_image(tmp_path / "missing.png")
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(InputError, match="empty file"):
        load_image(tmp_path / "empty.png")
    (tmp_path / "text.png").write_text("hello")
    with pytest.raises(InputError, match="not an image"):
        load_image(tmp_path / "text.png")
    with pytest.raises(InputError, match="is a folder"):
        load_image(tmp_path)


def test_load_image_gray_and_16bit(tmp_path):
    g = square()[:, :, 1]
    cv2.imwrite(str(tmp_path / "g.png"), g)
    cv2.imwrite(str(tmp_path / "g16.png"), g.astype(np.uint16) * 257)
    cv2.imwrite(str(tmp_path / "c.png"), square()[:, :, ::-1])
    assert load_image(tmp_path / "g.png").shape == (120, 160, 3)
    np.testing.assert_array_equal(load_image(tmp_path / "g16.png")[:, :, 0], g)
    np.testing.assert_array_equal(load_image(tmp_path / "c.png"), square())


def test_flat_image_has_no_edges():
    assert len(image_cloud(np.full((50, 50, 3), 128, np.uint8))) == 0


def _at_offset(a: np.ndarray, offset: int) -> np.ndarray:
    """A copy of ``a`` starting ``offset`` bytes into a fresh buffer (another alignment)."""
    buf = np.empty(a.nbytes + 64, np.uint8)[offset:offset + a.nbytes].view(a.dtype).reshape(a.shape)
    buf[...] = a
    return buf


def test_gradient_magnitude_is_correctly_rounded_whatever_the_buffer():
    from pcreg.registration.clouds import magnitude

    rng = np.random.default_rng(5)
    # Sobel responses of 8-bit images: integers up to 4 * 255 (their squares' sum is exact in float32)
    gx, gy = (rng.integers(-1020, 1021, (481, 643)).astype(np.float32) for _ in range(2))
    want = np.sqrt(gx.astype(np.float64) ** 2 + gy.astype(np.float64) ** 2).astype(np.float32)
    for offset in (0, 4, 8, 12, 36):
        got = magnitude(_at_offset(gx, offset), _at_offset(gy, offset + 4))
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, want)


def test_the_same_images_register_to_the_same_transform_and_field_in_any_buffer():
    import pcreg
    from pcreg.datasets import synthetic

    frames = synthetic("syn2a", 2, 0, width=640, height=480)
    a, b = frames[0].image, frames[1].image
    first = pcreg.register(a, b)
    first_dense = pcreg.register_dense(a, b)
    for offset in range(1, 6):
        np.testing.assert_array_equal(pcreg.register(_at_offset(a, offset), _at_offset(b, offset + 3)).matrix,
                                      first.matrix)
    for offset in (1, 2, 3):
        np.testing.assert_array_equal(
            pcreg.register_dense(_at_offset(a, offset), _at_offset(b, offset + 2)).field, first_dense.field)
