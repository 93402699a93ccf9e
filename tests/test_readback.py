"""pcreg.recording.readback: recordings of the layouts pcreg wrote before the current one (written here
with rerun directly) read back, and get the blueprint of what they hold."""

from __future__ import annotations

import numpy as np
import rerun as rr

from pcreg.recording import entities as E
from pcreg.recording.blueprint import panes
from pcreg.recording.readback import image, read_entities, read_recording
from pcreg.recording.staging import stage

H, W = 48, 64


def _image(seed: int) -> np.ndarray:
    """A test image that differs with ``seed``."""
    y, x = np.mgrid[0:H, 0:W]
    return np.stack([x * 4, y * 5, np.full_like(x, 40 * (seed % 5))], axis=-1).astype(np.uint8) + np.uint8(seed)


def _write_old(path, recording_id: str, log_frame) -> None:
    """A sequence recording of three frames written with rerun directly, ``log_frame(rec, f)`` at each."""
    rec = rr.RecordingStream("pcreg", recording_id=recording_id)
    rec.save(path)
    rec.send_property(E.PROPERTY, rr.AnyValues(**{E.KIND_FIELD: "sequence"}))
    for f in range(3):
        rec.set_time(E.FRAME_TIMELINE, sequence=f)
        log_frame(rec, f)
    rec.flush()
    rec.disconnect()


def test_raw_frames_of_the_layout_before_the_slots_read_back(tmp_path):
    """A recording of raw images made before the image slots (a Clear at registration/reference where the
    reference was the previous frame's moving image, written here with rerun directly): its references
    read back, and its Registration view draws moving/image one frame back, as it did."""
    path = tmp_path / "raw-old.rrd"

    def frame(rec, f):
        if f == 0:
            rec.log(E.REFERENCE_IMAGE, rr.Image(_image(9), color_model="RGB", draw_order=-9.0))
        elif f == 1:
            rec.log(E.REFERENCE_IMAGE, rr.Clear(recursive=False))
        rec.log(E.MOVING_IMAGE, rr.Image(_image(f), color_model="RGB", draw_order=-10.0))

    _write_old(path, "raw-old-layout", frame)
    back = read_recording(path)
    assert [back.reference(f).entity.strip("/") for f in range(3)] == [E.REFERENCE_IMAGE, E.MOVING_IMAGE, E.MOVING_IMAGE]
    for f, want in enumerate([_image(9), _image(0), _image(1)]):
        assert np.array_equal(image(back.reference(f)), want)
        assert np.array_equal(image(back.moving(f)), _image(f))
    registration = next(p for p in panes("sequence", read_entities(path)) if p.name == "Registration")
    moving = "/" + E.MOVING_IMAGE
    assert moving in registration.include and registration.offsets == ((moving, -1),)


def test_a_recording_of_the_old_layout_reads_back_and_gets_its_blueprint(tmp_path):
    """A recording made before each frame was stored once (every pair's reference logged at its frame,
    written here with rerun directly): its references read back, and its Registration view shows
    ``registration/reference`` alone, as it always did."""
    path = tmp_path / "old.rrd"

    def frame(rec, f):
        rec.log(E.REFERENCE_IMAGE, rr.Image(_image(f), color_model="RGB", draw_order=-10.0))
        rec.log(E.MOVING_IMAGE, rr.Image(_image(f + 1), color_model="RGB", draw_order=-10.0))
        rec.log(E.WARPED_IMAGE, rr.Image(_image(f + 1), color_model="RGB", opacity=0.5, draw_order=-5.0))

    _write_old(path, "old-layout", frame)
    back = read_recording(path)
    for f in range(3):
        assert back.reference(f).entity == "/" + E.REFERENCE_IMAGE
        assert np.array_equal(image(back.reference(f)), _image(f))
        assert np.array_equal(image(back.moving(f)), _image(f + 1))
    registration = next(p for p in panes("sequence", read_entities(path)) if p.name == "Registration")
    assert registration.offsets == () and "/" + E.MOVING_IMAGE not in registration.include
    # what `pcreg view` opens: the recording staged with the layout of what it holds
    staged = stage([path], tmp_path / "staged.rrd")
    assert staged.kinds == ("sequence",)
    shown = panes("sequence", read_entities(staged.path, timeline=E.FRAME_TIMELINE))
    assert [(p.name, p.include, p.offsets) for p in shown if p.name == "Registration"] == [
        ("Registration", ("/registration/**",), ())]
    assert np.array_equal(image(read_recording(staged.path).reference(2)), _image(2))
