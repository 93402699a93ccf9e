"""0.2.0's ``KeyRun(frames, keys, out, options, identity=..., truth=..., confidence=...)`` and its six-argument
``on_frame`` callback still work for one minor version, with a :class:`DeprecationWarning` naming the new spelling
(``KeyRun(Run(frames, out, identity, ...), keys, config)``), and label what the new spelling labels."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from PIL import Image

import pcreg
from pcreg.datasets.sources import FolderFrames
from pcreg.pipeline.config import PropagatorConfig
from pcreg.pipeline.keys_run import KeyRun
from pcreg.runs.run import Run


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    folder = tmp_path_factory.mktemp("frames")
    frames = pcreg.synthetic("syn1a", 5, 0, width=96, height=72)
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"f{i}.png"), f.image[:, :, ::-1])
    return folder, {0: frames[0].labels, 3: frames[3].labels}


def _labels(out):
    return [np.asarray(Image.open(out / f"f{i}.png")) for i in range(5)]


def test_the_constructor_of_0_2_labels_what_the_new_one_labels(tmp_path, clip):
    folder, keys = clip
    config, identity = PropagatorConfig(), {"frames": str(folder), "labels": "keys"}
    seen = []

    def on_frame(t, image, labels, report, name, size):  # 0.2.0's callback: no reference
        seen.append(name)

    with pytest.warns(DeprecationWarning, match=r"KeyRun\(pcreg\.runs\.run\.Run\(frames, out, identity") as said:
        old = KeyRun(FolderFrames(folder), keys, tmp_path / "old", config, identity=identity, confidence=True)
    assert said[0].filename == __file__  # the warning points at the caller's line
    assert old.out == tmp_path / "old" and old.identity == identity
    (tmp_path / "old").mkdir()
    old.start()
    assert old.run(on_frame) == 3
    assert sorted(seen) == ["f1.png", "f2.png", "f4.png"]
    assert (tmp_path / "old" / "confidence" / "f1.png").is_file()

    new = KeyRun(Run(FolderFrames(folder), tmp_path / "new", identity, confidence=True), keys, config, reading=None)
    (tmp_path / "new").mkdir()
    new.start()
    told = []
    assert new.run(lambda *a, reference=None: told.append(reference is not None)) == 3
    assert told and all(told)
    for a, b in zip(_labels(tmp_path / "old"), _labels(tmp_path / "new")):
        assert np.array_equal(a, b)


def test_every_spelling_0_2_took_and_what_it_refused(tmp_path, clip):
    """0.2.0's arguments by keyword, by position, mixed, and ``identity=None`` (0.2.0 took it): each the same run;
    what 0.2.0 refused (no identity, a fifth positional argument) is Python's TypeError, naming KeyRun()."""
    folder, keys = clip
    config = PropagatorConfig()
    spelled = [lambda f: KeyRun(frames=f, keys=keys, out=tmp_path, config=config, identity={"x": 1}),
               lambda f: KeyRun(f, keys, tmp_path, config=config, identity={"x": 1}),
               lambda f: KeyRun(f, keys, out=tmp_path, config=config, identity={"x": 1}, truth=None, confidence=True),
               lambda f: KeyRun(f, keys, tmp_path, config, identity=None)]
    for make in spelled:
        with pytest.warns(DeprecationWarning):
            job = make(FolderFrames(folder))
        assert job.out == tmp_path and job.config is config and sorted(job.keys) == [0, 3]
    assert job.identity is None
    for refused in (lambda f: KeyRun(f, keys, tmp_path, config), lambda f: KeyRun(f, keys, tmp_path, config, {"x": 1})):
        with pytest.raises(TypeError, match=r"^KeyRun\(\): "):
            refused(FolderFrames(folder))
    with pytest.raises(TypeError, match=r"^KeyRun\(\): .*'config'"):
        KeyRun(Run(FolderFrames(folder), tmp_path, {}), keys)
    job = KeyRun(owner=Run(FolderFrames(folder), tmp_path, {}), keys=keys, config=config)  # the new form by keyword
    assert job.config is config


def test_0_2s_options_dict_by_position_and_by_keyword_labels_what_its_configuration_labels(tmp_path, clip):
    """0.2.0 took the propagator's keywords as a dict (``options``, as its ``pcreg run`` made it): the deprecated form
    took only a PropagatorConfig, and 0.2.0's calls failed (an AttributeError of the dict in ``start``, or a TypeError
    for ``options=``)."""
    folder, keys = clip
    options = {"backend": "reference", "model": "dense", "init": "identity", "weight": 2.0}
    identity = {"frames": str(folder), "labels": "keys", **options}
    runs = {"position": lambda out: KeyRun(FolderFrames(folder), keys, out, options, identity=identity),
            "keyword": lambda out: KeyRun(frames=FolderFrames(folder), keys=keys, out=out, options=options, identity=identity),
            "config": lambda out: KeyRun(FolderFrames(folder), keys, out, PropagatorConfig(), identity=identity)}
    labelled = {}
    for how, make in runs.items():
        with pytest.warns(DeprecationWarning, match=r"KeyRun\(frames, keys, out, options"):
            job = make(tmp_path / how)
        assert job.config == PropagatorConfig()
        (tmp_path / how).mkdir()
        job.start()
        assert job.run(lambda *a: None) == 3
        labelled[how] = _labels(tmp_path / how)
    assert all(np.array_equal(a, b) for how in ("position", "keyword") for a, b in zip(labelled[how], labelled["config"]))
    with pytest.warns(DeprecationWarning):
        flow = KeyRun(FolderFrames(folder), keys, tmp_path, {**options, "model": "flow:fast", "scale": 0.5}, identity=None)
    assert flow.config == PropagatorConfig(model="flow", preset="fast", scale=0.5)
    with pytest.warns(DeprecationWarning), pytest.raises(TypeError, match=r"^KeyRun\(\): options must be a dict"):
        KeyRun(FolderFrames(folder), keys, tmp_path, "dense", identity=None)
