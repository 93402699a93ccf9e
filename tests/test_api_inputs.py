"""Arrays as users pass them to the public API: another byte order, an ndarray subclass, a masked array. Each is
read as the plain array it holds, or refused with an InputError naming the argument; never misread, never a
numpy error."""

from __future__ import annotations

import numpy as np
import pytest

import pcreg
from pcreg.classes.keys import check_labels
from pcreg.errors import InputError
from pcreg.frame import PreparedFrame, as_rgb_uint8


def _image(h=48, w=64, seed=0):
    """A smooth colour image with edges (a few discs on a gradient), uint8 RGB."""
    y, x = np.mgrid[:h, :w]
    img = np.dstack([x * 3, y * 4, (x + y) * 2]).astype(np.float64)
    rng = np.random.default_rng(seed)
    for cx, cy, r in zip(rng.integers(8, w - 8, 4), rng.integers(8, h - 8, 4), rng.integers(4, 9, 4)):
        img[(x - cx) ** 2 + (y - cy) ** 2 < r * r] = rng.integers(0, 256, 3)
    return np.clip(img, 0, 255).astype(np.uint8)


T = np.array([[1.0, 0.0, 2.5], [0.0, 1.0, -1.5], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("dtype, scale", [(">u2", 257), (">f4", 1 / 255), (">f8", 1 / 255)], ids=[">u2", ">f4", ">f8"])
def test_a_big_endian_image_is_read_as_the_same_image_in_the_machines_byte_order(dtype, scale):
    """A FITS reader or a raw file gives ``>u2``; every image entry point reads it as it reads ``<u2``
    (it was "unsupported image dtype >u2", and warp refused ``>f4``)."""
    img = _image()
    native = (img * float(scale)).astype(np.dtype(dtype).newbyteorder("="))
    big = native.astype(dtype)
    assert not big.dtype.isnative
    np.testing.assert_array_equal(as_rgb_uint8(big), as_rgb_uint8(native))
    np.testing.assert_array_equal(pcreg.image_cloud(big).points, pcreg.image_cloud(native).points)
    warped, valid = pcreg.warp(big, T)
    expected, expected_valid = pcreg.warp(native, T)
    assert warped.dtype == native.dtype and warped.dtype.isnative
    np.testing.assert_array_equal(warped, expected)
    np.testing.assert_array_equal(valid, expected_valid)


@pytest.mark.filterwarnings("ignore:the matrix subclass:PendingDeprecationWarning")
def test_an_np_matrix_is_read_as_the_grey_image_it_holds():
    """``np.matrix`` cannot grow a third axis: turning it into RGB raised numpy's "shape too large to be a matrix"."""
    grey = _image()[:, :, 1]
    np.testing.assert_array_equal(as_rgb_uint8(np.matrix(grey)), as_rgb_uint8(grey))
    assert PreparedFrame.of(np.matrix(grey)).shape == grey.shape
    np.testing.assert_array_equal(pcreg.image_cloud(np.matrix(grey)).points, pcreg.image_cloud(grey).points)


def test_a_masked_array_is_refused_where_something_is_masked_and_read_where_nothing_is():
    """numpy gives the values stored under a mask; reading them as an image, a cloud or labels would use what the
    user masked out, so such an array is refused, naming the argument. With nothing masked it is its data."""
    img = _image()
    hidden = np.ma.masked_array(img, mask=np.zeros(img.shape, bool))
    hidden.mask[:10] = True
    for call, name in ((lambda: pcreg.image_cloud(hidden), "image"), (lambda: pcreg.warp(hidden, T), "warp"),
                       (lambda: PreparedFrame.of(hidden, name="key frame"), "key frame")):
        with pytest.raises(InputError, match=f"^{name}: a masked array with 1920 masked value"):
            call()
    points = np.random.default_rng(1).normal(size=(50, 2)) * 10
    gone = np.zeros(points.shape, bool)
    gone[7, 1] = True
    with pytest.raises(InputError, match="^source: a masked array with 1 masked value"):
        pcreg.icp(np.ma.masked_array(points, mask=gone), points)
    labels = np.zeros(img.shape[:2], np.uint8)
    with pytest.raises(InputError, match="^labels: a masked array"):
        check_labels(np.ma.masked_array(labels, mask=labels == 0), labels.shape)
    clear = np.ma.masked_array(img)
    np.testing.assert_array_equal(as_rgb_uint8(clear), img)
    np.testing.assert_array_equal(pcreg.warp(clear, T)[0], pcreg.warp(img, T)[0])
    assert pcreg.icp(np.ma.masked_array(points), points).fitness == 1.0


@pytest.mark.parametrize("dtype", [np.int8, np.int64])
def test_a_negative_label_is_named_in_the_refusal(dtype):
    """The refusal named the largest value (0 or 1, both valid) when the bad one was negative."""
    labels = np.zeros((16, 16), dtype)
    labels[3, 4] = -1
    with pytest.raises(InputError, match="found -1$"):
        check_labels(labels, labels.shape)


def test_colour_key_labels_given_as_an_array_are_refused_not_read_by_their_red_channel():
    """An (H, W, 3) colour label image given to the stream was read as its red channel's values: CamVid's car
    (64, 0, 128) and road (128, 64, 128) became ids 64 and 128, or ground where red is 0, without a word.
    Ids saved as grey in three channels, with or without an alpha, are read as before."""
    ids = np.zeros((16, 16), np.uint8)
    ids[4:, :] = 1
    colour = np.zeros((16, 16, 3), np.uint8)
    colour[4:, :] = (0, 0, 1)
    with pytest.raises(InputError, match=r"^labels of shape \(16, 16, 3\) whose channels differ: a colour label image"):
        check_labels(colour, (16, 16))
    image = np.random.default_rng(0).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    with pytest.raises(InputError, match="whose channels differ"):
        pcreg.Propagator.from_key_frame(image, colour)
    grey = np.repeat(ids[:, :, None], 3, axis=2)
    np.testing.assert_array_equal(check_labels(grey, (16, 16)), ids)
    with_alpha = np.dstack([grey, np.full((16, 16), 255, np.uint8)])
    np.testing.assert_array_equal(check_labels(with_alpha, (16, 16)), ids)


@pytest.mark.parametrize("dtype, fill", [(np.float32, 1e300), (np.float32, -1e39), (np.float16, 1e6)])
def test_a_fill_beyond_a_float_arrays_range_is_refused(dtype, fill):
    """The border was filled with NaN (float32, 1e300) or inf (float16), silently."""
    with pytest.raises(InputError, match=f"^warp: fill .* is beyond the range of the {np.dtype(dtype)} array"):
        pcreg.warp(np.zeros((20, 20), dtype), T, fill=fill)
    largest = float(np.finfo(dtype).max)
    warped, valid = pcreg.warp(np.zeros((20, 20), dtype), T, fill=largest, interpolation="nearest")
    assert np.all(warped[~valid] == largest)


@pytest.mark.parametrize("backend", ["reference", "open3d"])
def test_a_schedule_whose_last_voxel_size_leaves_too_few_points_is_refused(backend):
    """A voxel as large as the cloud leaves one point at the scale that gives the result: the reference ICP
    returned the identity, Open3D's the centroids' shift with no rotation, both with a fitness of 1."""
    angle = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    source = np.c_[30 * np.cos(angle) + 5 * np.cos(3 * angle), 20 * np.sin(angle)]
    target = source @ np.array([[0.999, -0.035], [0.035, 0.999]]).T + [0.5, -0.3]
    for sizes in ((1e6,), (1.0, 1e6)):
        with pytest.raises(InputError, match=r"^voxel_sizes: at the last size, 1e\+06, the source is downsampled to 1 "
                                             r"point\(s\): 1 point\(s\) are too few for the rigid model"):
            pcreg.icp(source, target, pcreg.ICPOptions(backend=backend, schedule=pcreg.VoxelSchedule(sizes)))
    coarse_first = pcreg.icp(source, target, pcreg.ICPOptions(backend=backend, schedule=pcreg.VoxelSchedule((1e6, 1.0))))
    assert coarse_first.converged and coarse_first.fitness == 1.0


@pytest.mark.parametrize("n", [2, 50])
def test_points_on_one_line_are_refused_by_the_open3d_backend_and_registered_by_the_reference(n):
    """Lifted to 3-D, a line leaves Open3D's ICP the rotation about it: it turned the plane over under some
    motions (a RegistrationError, "mirrors the image plane") and not under others, so the backend refuses the line
    at once; the reference ICP, in 2-D, recovers the rotation (the shift along the line is up to a point's spacing)."""
    from pcreg import transforms as tf

    line = np.c_[np.linspace(0, 49, n), np.linspace(0, 24.5, n)]
    rng = np.random.default_rng(0)
    for _ in range(5):
        T_true = tf.rigid2d(rng.uniform(-5, 5), *rng.uniform(-1, 1, 2))
        target = tf.apply(T_true, line)
        with pytest.raises(InputError, match="^source: its points lie on one line.*use backend='reference'"):
            pcreg.icp(line, target, pcreg.ICPOptions(backend="open3d", max_correspondence_distance=5))
        fit = pcreg.icp(line, target, pcreg.ICPOptions(max_correspondence_distance=5))
        np.testing.assert_allclose(fit.matrix[:2, :2], T_true[:2, :2], atol=1e-9)


def test_a_float_image_off_by_a_rounding_error_is_read_and_one_beyond_half_a_level_is_refused():
    """``np.nextafter(img, 2)`` holds 1.0000000000000002: it was refused as "got 4.94066e-324..1", values that
    read as in range. Within half an 8-bit level of [0, 1] a value rounds to 0 or 255; beyond it is refused."""
    img = _image()
    unit = img / 255.0
    for near in (np.nextafter(unit, 2), np.nextafter(unit, -1), (unit + 0.49 / 255).astype(np.float32),
                 unit - 0.49 / 255):
        np.testing.assert_array_equal(as_rgb_uint8(near), img)
    for value, said in ((1.003, r"0\.\.1\.003"), (-0.003, r"-0\.003\.\.1")):
        far = np.zeros(img.shape)
        far[0, 0, 0], far[1, 0, 0] = value, 1.0
        with pytest.raises(InputError,
                           match=f"^image: a float image must hold values in \\[0, 1\\], got {said}; divide an array "):
            as_rgb_uint8(far)


def test_a_pyramid_of_another_image_of_the_same_size_is_refused():
    """Only the size was checked: the moving image's pyramid given as the reference's registered the moving image to
    itself (the identity, fitness 1, every plausibility figure perfect)."""
    from pcreg.registration.clouds import image_pyramid

    frames = pcreg.synthetic("syn2a", n_frames=2, width=160, height=120)
    a, b = frames[0].image, frames[1].image
    with pytest.raises(InputError, match="^reference pyramid was built for another image of this size"):
        pcreg.register(a, b, reference_pyramid=image_pyramid(b))
    with pytest.raises(InputError, match="^moving pyramid was built for another image of this size"):
        pcreg.register(a, b, moving_pyramid=image_pyramid(a))
    same = pcreg.register(a, b, reference_pyramid=image_pyramid(a.copy()), moving_pyramid=image_pyramid(b / 255.0))
    np.testing.assert_allclose(same.matrix, pcreg.register(a, b).matrix, atol=1e-9)


@pytest.mark.parametrize("model, start, said", [
    ("rigid", np.diag([1.1, 1.1, 1.0]), "not orthonormal"), ("rigid", np.diag([-1.0, 1.0, 1.0]), "a reflection"),
    ("similarity", np.array([[1, 0, 0], [0, 1, 0], [2e-4, 0, 1.0]]), "a projection's"),
    ("similarity", np.array([[1, 0.1, 0], [0, 1, 0], [0, 0, 1.0]]), "not a rotation times a scale")])
def test_register_refuses_an_init_its_model_cannot_hold(model, start, said):
    """The ICP keeps the kind of transform its start is: a scaled start under the rigid model came back scaled
    (6 px off at the corners with the test off), a projective or sheared one under the similarity model projective
    or sheared. :func:`pcreg.icp` refuses the same starts."""
    ref = _image(120, 160)
    with pytest.raises(InputError, match=f"^init: .*{said}.* the {model} ICP"):
        pcreg.register(ref, ref, model=model, init=T @ start)
    points = np.random.default_rng(2).normal(size=(100, 2)) * 20
    with pytest.raises(InputError, match=f"^init: .*{said}.* the {model} ICP"):
        pcreg.icp(points, points, pcreg.ICPOptions(model=model), init=T @ start)
    held = T @ np.diag([2.0, 2.0, 1.0]) if model == "similarity" else T  # a scale is a similarity's
    assert pcreg.icp(points, points, pcreg.ICPOptions(model=model), init=held).fitness > 0


@pytest.mark.parametrize("which", ["reference_mask", "moving_mask"])
def test_a_mask_with_no_usable_pixel_or_a_nan_is_refused_as_the_mask(which):
    """An all-false mask ended in a refused registration ("the moving image has no usable edges", exit 3), which
    named neither the mask nor why; a float mask with NaN counted NaN as usable."""
    ref = pcreg.synthetic("syn2a", n_frames=1, width=160, height=120)[0].image
    with pytest.raises(InputError, match=f"^{which} marks no pixel usable"):
        pcreg.register(ref, ref, **{which: np.zeros((120, 160), bool)})
    nan = np.ones((120, 160), np.float32)
    nan[0, 0] = np.nan
    with pytest.raises(InputError, match=f"^{which} holds NaN or inf"):
        pcreg.register(ref, ref, **{which: nan})
    some = np.zeros((120, 160), bool)
    some[20:100, 30:130] = True
    assert pcreg.register(ref, ref, **{which: some}).inlier_ratio > 0.5


def _stream_key(h=120, w=160):
    """A key frame and its two-class labels: a textured left half (ground) and a bright right half (obstacle)."""
    img = _image(h, w)
    labels = np.zeros((h, w), np.uint8)
    labels[:, w // 2:] = 1
    img[:, w // 2:] = np.clip(img[:, w // 2:].astype(int) + 120, 0, 255).astype(np.uint8)
    return img, labels


def test_a_refused_key_frame_leaves_the_stream_as_it_was():
    """``reset`` kept the refused frame's size: every later frame of the stream was refused as of another size."""
    key, labels = _stream_key()
    prop = pcreg.Propagator.from_key_frame(key, labels, model="flow")
    with pytest.raises(InputError, match="too small for the flow model"):
        prop.reset(key[:20, :20], labels[:20, :20])
    again = pcreg.Propagator.from_key_frame(key, labels, model="flow")
    np.testing.assert_array_equal(prop.step(key), again.step(key))


class _Scores:
    """A classifier of the two classes whose ``decision_function`` returns what it is given."""

    classes_ = np.array([0, 1])
    class_prior_ = np.array([0.5, 0.5])

    def __init__(self, scores):
        self.scores = scores

    def decision_function(self, image):
        return self.scores(np.asarray(image).shape[:2])


@pytest.mark.parametrize("scores, said", [
    (lambda s: np.full(s, np.nan), "returned NaN or inf at 19200 of its scores"),  # every pixel ground, unmarked
    (lambda s: np.zeros(s).T, r"returned shape \(160, 120\) for a frame of 160x120"),  # labels 160x120 returned
    (lambda s: np.zeros((3, 3)), r"returned shape \(3, 3\)"),
    (lambda s: np.zeros(s[0]), r"returned shape \(120,\)"),
    (lambda s: "abc", "returned str that holds no numbers"),
])
def test_what_a_classifier_of_ones_own_returns_is_checked(scores, said):
    key, labels = _stream_key()
    for trust in ("default", None):
        prop = pcreg.Propagator(_Scores(scores), **({} if trust == "default" else {"trust": None}))
        prop.reset(key, labels)
        with pytest.raises(InputError, match=f"the classifier _Scores's decision_function {said}"):
            prop.step(key)


@pytest.mark.parametrize("spec", [5, 3.5, b"lagr", [], {}])
def test_a_class_table_of_another_type_is_an_input_error(spec):
    with pytest.raises(InputError, match="classes must be a pcreg.classes.ClassTable, a built-in table's name"):
        pcreg.error_rate(np.zeros((2, 2), np.uint8), np.zeros((2, 2), np.uint8), classes=spec)


def test_error_rate_refuses_masked_values_and_masks_that_are_not_true_or_false():
    truth = np.ma.masked_array([[0, 1]], mask=[[False, True]])
    with pytest.raises(InputError, match="truth: a masked array with 1 masked value"):
        pcreg.error_rate(np.array([[0, 0]]), truth)  # 50.0: the masked pixel scored
    for mask in (np.array([["a", "b"]]), np.array([[np.nan, 1.0]]), np.array([[2, 1]]), np.array([[None, None]])):
        with pytest.raises(InputError, match="mask must be a bool array"):
            pcreg.error_rate(np.array([[0, 0]]), np.array([[0, 1]]), mask=mask)
    assert pcreg.error_rate(np.array([[0, 0]]), np.array([[0, 1]]), mask=np.array([[1, 0]])) == 0.0


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.bool_])
def test_a_fill_beyond_an_integer_range_saturates(dtype):
    """OpenCV rounded a fill past 2^31 to 0: ``fill=3e9`` filled a uint8 array with 0, ``1e9`` with 255."""
    moving = np.ones((6, 6), dtype)
    top = 1 if dtype is np.bool_ else np.iinfo(dtype).max
    for fill in (1e9, 3e9, 1e300):
        assert pcreg.warp(moving, T, fill=fill)[0][0, 0] == top
    assert pcreg.warp(moving, T, fill=-3e9)[0][0, 0] == 0


def test_complex_motions_and_numbers_beyond_range_are_input_errors():
    from pcreg.registration.dense import Membrane

    img = _image()
    for motion in (T.astype(complex), np.zeros((48, 64, 2), complex)):
        with pytest.raises(InputError, match="complex numbers; give its real values"):
            pcreg.warp(img, motion)
    with pytest.raises(InputError, match="global_result: complex numbers"):
        pcreg.register_dense(img, img, global_result=np.eye(3).astype(complex))
    with pytest.raises(InputError, match="membrane weight"):  # OverflowError before
        Membrane(grid_spacing=1e300)


def test_a_learned_histogram_of_no_numbers_is_refused_on_resume():
    key, labels = _stream_key()
    prop = pcreg.Propagator.from_key_frame(key, labels)
    prop.step(key)
    for learned in ("abc", np.zeros(prop.learned.shape, complex)):
        again = pcreg.Propagator.from_key_frame(key, labels)
        with pytest.raises(InputError, match="a learned histogram must be finite"):
            again.resume(1, prop.carry, learned)


@pytest.mark.parametrize("size", [(80, 60), (64, 48)])
def test_another_scene_is_a_cut_at_sizes_too_small_for_the_flow_of_the_cut_test(size):
    """The cut test works at half size, and DIS takes 32 px a side: below a working size of 64 px the test was
    skipped and said no cut, so noise or a black frame kept a confidence of 0.94-0.98 (predicted error 2-6%)."""
    w, h = size
    key, labels = _stream_key(h, w)
    for other in (np.random.default_rng(0).integers(0, 256, key.shape, dtype=np.uint8), np.zeros_like(key)):
        prop = pcreg.Propagator.from_key_frame(key, labels)
        prop.step(other)
        assert prop.last.trust_summary["cut"] is True and float(prop.last.confidence.max()) == 0.5
    prop = pcreg.Propagator.from_key_frame(key, labels)
    prop.step(np.roll(key, 1, axis=1))  # the same scene, moved
    assert prop.last.trust_summary["cut"] is False and float(prop.last.confidence.mean()) > 0.8


def test_a_bool_mask_warped_linearly_keeps_what_is_at_least_half_inside():
    """A line 1 px wide shifted by half a pixel came back empty (the mask went through OpenCV as 0 and 1, each pixel
    rounded to 0); as a uint8 0/255 mask the same warp keeps it at 128."""
    import pcreg

    mask = np.zeros((40, 160), bool)
    mask[20, 20:140] = True
    T = np.eye(3)
    T[1, 2] = 0.5
    warped, valid = pcreg.warp(mask, T)
    assert warped.dtype == bool and warped[20:22, 20:140].all() and warped.sum() == 240
    assert pcreg.warp(mask, T, interpolation="nearest")[0].sum() == 120
    as_uint8 = pcreg.warp(mask.astype(np.uint8) * 255, T)[0]
    assert np.array_equal(warped, as_uint8 >= 128)
