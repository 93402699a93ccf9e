"""A key frame the stream's classifier cannot label: :meth:`pcreg.Propagator.reset` to labels holding a class the
classifier was not fitted on, or no known label at all, and :func:`pcreg.pipeline.keyframes.label_clip` given a
classifier of one table and key labels of another, or inputs that are not a clip's."""

import numpy as np
import pytest

from pcreg.classes import CAMVID11, LAGR
from pcreg.classification.bayes import fit_classifier
from pcreg.datasets import Frame
from pcreg.errors import InputError
from pcreg.pipeline.keyframes import label_clip
from pcreg.pipeline.stream import Propagator



@pytest.fixture(scope="module")
def clip(shared_data):
    from pcreg.datasets import load_dataset

    frames = load_dataset(f"camvid:{shared_data / 'camvid'}", n_frames=4, classes=CAMVID11)["0001TP"]
    return [f.image for f in frames], [f.labels for f in frames]


def test_a_key_frame_holding_a_class_the_classifier_never_saw_is_refused(clip):
    """Fence drawn on the second key frame, which the first (and so the classifier) does not show: the stream
    labelled no pixel fence (0%, 11% of the key frame), its predicted error 11%, and said nothing."""
    images, labels = clip
    prop, twin = (Propagator.from_key_frame(images[0], labels[0], classes=CAMVID11) for _ in range(2))
    fence = CAMVID11.id_of("fence")
    assert fence not in prop.classes
    key = np.where(labels[1] == CAMVID11.id_of("road"), fence, labels[1]).astype(np.uint8)
    prop.step(images[1]), twin.step(images[1])
    with pytest.raises(InputError, match=r"^the key frame's labels hold fence \(id 7\), which the classifier was "
                                         r"not fitted on"):
        prop.reset(images[1], key)
    with pytest.raises(InputError, match=r"^the key frame's labels are all unknown \(11\): nothing to propagate"):
        prop.reset(images[1], np.full_like(labels[1], CAMVID11.unknown))
    assert np.array_equal(prop.step(images[2]), twin.step(images[2]))  # refused, the stream is as it was
    prop.reset(images[1], labels[1])  # its own classes: taken


def test_label_clip_refuses_a_classifier_of_another_table_than_the_keys(clip):
    images, labels = clip
    clf = fit_classifier([Frame(images[0], labels[0], "0")], classes=CAMVID11)
    lagr = np.array([0, 0, 1, 0, 0, 1, 1, 1, 1, 1, 1, 2], np.uint8)[labels[0]]
    with pytest.raises(InputError, match=r"^the classifier's class table \(camvid11\) is not the key labels' \(lagr\): class 0 is sky"):
        label_clip(images.__getitem__, 3, {0: lagr}, classifier=clf, classes=LAGR)
    # the classifier's table, when no other is given
    out = label_clip(images.__getitem__, 3, {0: labels[0]}, classifier=clf, model="flow")
    assert set(np.unique(out[2].labels)) <= set(CAMVID11.ids)


@pytest.mark.parametrize("keys, n, said", [
    ({2.5: "k"}, 4, "a key frame's index must be an integer"),
    ({"0": "k"}, 4, "a key frame's index must be an integer"),
    ({0: "k", 7: "k"}, 4, "a key frame's index must be"),
    (["k"], 4, "keys must be a mapping"),
    ({0: "k"}, 6.0, "the clip's frames must be an integer"),
])
def test_label_clip_names_inputs_that_are_no_clip(keys, n, said):
    image = np.zeros((48, 64, 3), np.uint8)
    key = np.zeros((48, 64), np.uint8)
    key[24:] = 1
    keys = [key] if isinstance(keys, list) else {k: key for k in keys}
    with pytest.raises(InputError, match=said):
        label_clip(lambda t: image, n, keys)
    with pytest.raises(InputError, match="images must be a function"):
        label_clip([image] * 4, 4, {0: key})


@pytest.mark.parametrize("bad, said", [
    (lambda key: np.where(key == 1, 7, key).astype(np.uint8), r"^key frame 3: label value 7 is not a class id"),
    (lambda key: np.dstack([key] * 3), r"^key frame 3: labels must be \(H, W\)"),
    (lambda key: key.astype(np.float32), r"^key frame 3: labels must be integers"),
])
def test_label_clip_names_the_key_frame_whose_labels_are_wrong(bad, said):
    """A key frame's labels that are not the table's class ids were named "training pair 1" (the classifier's
    count of the frames it was fitted on), not the key frame."""
    image = np.zeros((48, 64, 3), np.uint8)
    key = np.zeros((48, 64), np.uint8)
    key[24:] = 1
    with pytest.raises(InputError, match=said):
        label_clip(lambda t: image, 5, {0: key, 3: bad(key)})
