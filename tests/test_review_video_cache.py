"""``pcreg view RUN --web`` of a run on a video keeps the frames it decoded in ``RUN/.pcreg-review/frames-KEY``, KEY
of the video's path, size and time. A video changed since (re-encoded, touched) gets a folder of its own, and the
folders of its earlier versions, never read again, were left there for good (a whole video's frames as JPEG each).
The review removes them when it makes the folder of the video as it is now, and only them: a folder holding
anything else is left."""

from __future__ import annotations

import os
import urllib.request

from _runs import video_run


def _get(url: str) -> int:
    with urllib.request.urlopen(url, timeout=60) as r:
        r.read()
        return r.status


def test_the_frames_decoded_from_an_earlier_version_of_the_video_are_removed(tmp_path):
    from pcreg.recording.review import ReviewServer
    from pcreg.review import CACHE, read_review

    video, out = video_run(tmp_path, 4)
    with ReviewServer(read_review(out), web_port=0) as server:
        assert _get(server.url + "frame/3.jpg") == 200
    [first] = (out / CACHE).iterdir()
    assert first.name.startswith("frames-") and any(first.iterdir())
    foreign = out / CACHE / "frames-0123456789ab"  # named as the review names its folders, holding another file
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine\n")
    other = out / CACHE / "frames-mine"
    other.mkdir()
    (other / "000000.jpg").write_bytes(b"")
    st = video.stat()
    os.utime(video, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # the video changed since (as re-encoded in place)
    with ReviewServer(read_review(out), web_port=0) as server:
        assert _get(server.url + "frame/3.jpg") == 200
    now = {p.name for p in (out / CACHE).iterdir()}
    assert first.name not in now and {foreign.name, other.name} < now and len(now) == 3, now
    assert (foreign / "notes.txt").read_text() == "mine\n"
