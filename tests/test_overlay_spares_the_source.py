"""``pcreg view RUN --overlay FILE.mp4 --force`` never writes over the video the run was labelled from, which the
command reads to draw the overlay: ``--force`` overwrites an earlier overlay, not an input. What an overlay killed
mid-write left beside it is removed by the next."""

from __future__ import annotations

from _runs import video_run
from _view import one_line_error, pcreg_view


def test_the_overlay_is_refused_over_the_runs_own_video(tmp_path, capsys):
    video, out = video_run(tmp_path)
    before = video.read_bytes()
    capsys.readouterr()
    assert pcreg_view([str(out), "--overlay", str(video), "--force"]) == 2
    assert one_line_error(capsys) == (f"pcreg: error: {video} is the input {video}; the output would overwrite it "
                                      "(choose another file)\n")
    assert video.read_bytes() == before
    assert pcreg_view([str(out), "--overlay", str(tmp_path / "overlay.mp4")]) == 0


def test_what_a_killed_overlay_left_is_removed_and_one_being_written_kept(tmp_path):
    """An overlay killed mid-write (kill -9, power lost) left its temporary MP4, as large as the frames it held,
    hidden beside the overlay for good; the next overlay of that name removes it, not one still being written."""
    import av

    from pcreg.outputs import atomic_file
    from _runs import killed_mid_write

    _, out = video_run(tmp_path)
    overlay = tmp_path / "overlay.mp4"
    killed = killed_mid_write(overlay)
    with atomic_file(overlay) as fh:  # another overlay of that name under way
        fh.write(b"\0")
        [writing] = set(tmp_path.glob(".overlay.mp4.*.tmp")) - {killed}
        assert pcreg_view([str(out), "--overlay", str(overlay)]) == 0
        assert not killed.exists() and writing.is_file()
        with av.open(str(overlay)) as container:
            assert sum(1 for _ in container.decode(video=0)) == 3
