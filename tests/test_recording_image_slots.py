"""A sequence's recording (each frame's reference the previous frame's moving image) drew nothing in its Moving view
from its fourth frame on once its images passed about 384 KiB (88 frames of 160x120 noise; the screenshot at any
such frame empty): the image slot hidden as the old reference and given the frame's moving image got two
Transform3D rows at one frame, batched into two chunks, and the viewer's transform cache kept the hidden one. One
row a slot and frame now."""

import sys
from collections import Counter

import cv2
import numpy as np
import pytest

from pcreg.cli import main
from pcreg.recording import viewer as view
from pcreg.recording.readback import read_recording
from pcreg.recording.recorder import Recorder

N = 100
BLUE = (20, 20, 230)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """A sequence of N frames of noise (the last moving image blue), each frame's reference the one before."""
    rng = np.random.default_rng(0)
    noise = [rng.integers(0, 256, (120, 160, 3), dtype=np.uint8) for _ in range(8)]
    blue = np.zeros((120, 160, 3), np.uint8)
    blue[:] = BLUE
    frames = [noise[i % 8] for i in range(N - 1)] + [blue]
    path = tmp_path_factory.mktemp("slots") / "seq.rrd"
    with Recorder(path, kind="sequence") as rec:
        for f in range(N):
            rec.set_frame(f)
            rec.log_images(reference=frames[f - 1] if f else np.full_like(blue, 128), moving=frames[f])
            rec.log_errors({"plain": 0.1 + f})
    return path, frames


def test_each_image_slot_has_one_place_a_frame(sequence):
    rec = read_recording(sequence[0])
    for slot in ("images/0", "images/1"):
        frames = Counter(r.times["frame"] for r in rec.get(slot, "Transform3D:translation"))
        assert set(frames) >= set(range(1, N)) and set(frames.values()) == {1}, (slot, frames)  # (one is new at 1)


@pytest.mark.slow
@pytest.mark.parametrize("frame", [5, N - 1])
def test_the_moving_view_draws_late_frames_of_a_long_sequence(sequence, tmp_path, capsys, frame):
    if sys.platform.startswith("linux") and not view.vulkan_icds():
        pytest.skip("no Vulkan driver (ICD) on this machine: install Debian's mesa-vulkan-drivers for lavapipe")
    path, frames = sequence
    out = tmp_path / "moving.png"
    code = main(["view", str(path), "--screenshot", str(out), "--time", f"frame={frame}", "--view", "Moving",
                 "--size", "1280x720"])
    assert code == 0, capsys.readouterr().err
    shot = cv2.imread(str(out), cv2.IMREAD_COLOR)
    assert shot.std() > 20, shot.std()  # an empty view is flat (about 1.6)
    if frame == N - 1:
        b, g, r = (shot[..., i].astype(int) for i in range(3))
        assert ((b > 150) & (r < 90) & (g < 90)).mean() > 0.05
