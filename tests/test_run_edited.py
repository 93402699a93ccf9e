"""`pcreg run` over an output folder edited by hand between two runs: what the resumed run cannot continue is
refused in one line naming the file (exit 2), as the export refuses it, never continued into a folder the export
then cannot read."""

from __future__ import annotations

import cv2
import numpy as np

from pcreg.cli import main
from _runs import drifting_frames, kill_before_commit, one_line_errors


def _video(folder, path):
    """The PNG frames of ``folder`` as an MJPEG AVI at ``path``."""
    frames = [cv2.imread(str(p)) for p in sorted(folder.glob("*.png"))]
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (w, h))
    for f in frames:
        writer.write(np.ascontiguousarray(f))
    writer.release()
    return path


def test_a_stopped_video_run_whose_steps_line_was_edited_is_refused_on_resume(tmp_path, monkeypatch, capsys):
    """A video's run stopped, a counted line of its steps.jsonl edited into no step, run again: refused naming the
    line, as a folder's run is (and as the export refuses it); before, the run went on and finished (exit 0) and
    only the export said the folder was broken."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=6)
    video = _video(folder, tmp_path / "clip.avi")
    out = tmp_path / "out"
    run = ["run", str(video), "--labels", str(key), "--out", str(out)]
    kill_before_commit(monkeypatch, 4)
    assert main(run) == 130
    monkeypatch.undo()
    lines = (out / "steps.jsonl").read_bytes().splitlines(keepends=True)
    (out / "steps.jsonl").write_bytes(lines[0] + b'{"frame": "two"}\n' + b"".join(lines[2:]))
    capsys.readouterr()
    assert main(run) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "steps.jsonl: line 2 is not a step pcreg run wrote" in err[0], err
    assert not (out / "000005.png").exists()


def test_a_key_frames_run_whose_frame_was_renamed_says_the_frames_changed(tmp_path, capsys):
    """A frame between two key frames renamed after a run from a folder of key frames: the run again is refused
    saying the frames changed (the name it labelled, the name there now), as a run from one label image says it;
    before, it said the new name's label PNG was missing though run.json counted it labelled, and a step whose name
    was edited went through as "all frames already done" while the export refused the folder."""
    from _runs import key_frames_of

    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=6)
    keys = key_frames_of(key, tmp_path / "keys", positions=(0, 5))
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(keys), "--out", str(out)]
    assert main(run) == 0
    (folder / "f2.png").rename(folder / "f2b.png")
    capsys.readouterr()
    assert main(run) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "labelled f2.png as frame 2" in err[0] and "holds as f2b.png" in err[0], err
    (folder / "f2b.png").rename(folder / "f2.png")
    lines = (out / "steps.jsonl").read_text().splitlines(keepends=True)
    lines[1] = lines[1].replace('"name": "f', '"name": "g')
    (out / "steps.jsonl").write_text("".join(lines))
    capsys.readouterr()
    assert main(run) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "the frames changed since the run began" in err[0], err


def _written_again(path):
    """The frame at ``path`` written again with its top rows darkened (a frame re-extracted or edited: its bytes change)."""
    image = cv2.imread(str(path))
    image[:4] = 0
    cv2.imwrite(str(path), image)


def _refused_while_written_again(run, path, said, capsys):
    """``path`` written again: ``run`` refused in one line naming it and its size then (``said`` before the
    sizes); put back, ``run`` is done (exit 0)."""
    kept = path.read_bytes()
    _written_again(path)
    capsys.readouterr()
    assert main(run) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"{path}: changed since the run in {run[-1]} {said}{len(kept)} bytes then" in err[0], err
    path.write_bytes(kept)
    assert main(run) == 0


def _without_sizes(out, kept=("bytes", "mtime_ns", "digest"), state_kept=("key_bytes", "key_contents")):
    """``out``'s run as a run from before the frames' sizes were kept: none of ``kept`` in its steps, none of
    ``state_kept`` in its run.json (by default no ``bytes``, ``mtime_ns`` or ``digest``; no ``key_bytes`` or
    ``key_contents``)."""
    import json

    lines = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
    (out / "steps.jsonl").write_text("".join(json.dumps({k: v for k, v in s.items() if k not in kept}) + "\n"
                                             for s in lines))
    state = json.loads((out / "run.json").read_text())
    for name in state_kept:
        state.pop(name)
    (out / "run.json").write_text(json.dumps(state))


def _same_size_other_frame(path, other):
    """The frame at ``path`` written again as ``other``'s picture, to the same size (an uncompressed BMP)."""
    before = path.stat().st_size
    cv2.imwrite(str(path), cv2.imread(str(other)))
    assert path.stat().st_size == before


def test_a_frame_written_again_to_the_same_size_is_refused_and_one_only_touched_resumes(tmp_path, capsys):
    """Uncompressed frames (BMP) of one size: a frame written again as another frame's picture keeps its size in
    bytes, which alone was checked: the run again went on as "all frames already done" with labels of a frame no
    longer there. Its modification time changed, so the digest of its bytes is read and told apart: refused, the key
    frame too, a run from one label image and from key frames alike. A frame touched (its time changed, its bytes
    not) resumes; a run from before the digests were kept resumes unchecked, as before."""
    import os

    from _runs import key_frames_of

    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=6)
    for p in sorted(folder.glob("*.png")):
        cv2.imwrite(str(p.with_suffix(".bmp")), cv2.imread(str(p)))
        p.unlink()
    keys = key_frames_of(key, tmp_path / "keys", positions=(0, 5))
    for labels, out in ((key, tmp_path / "one"), (keys, tmp_path / "keyed")):
        run = ["run", str(folder), "--labels", str(labels), "--out", str(out)]
        assert main(run) == 0
        for name, said in (("f2.bmp", "labelled it"), ("f0.bmp", "labelled from it")):
            path = folder / name
            kept = path.read_bytes()
            _same_size_other_frame(path, folder / "f4.bmp")
            capsys.readouterr()
            assert main(run) == 2
            err = one_line_errors(capsys)
            assert len(err) == 1 and f"{path}: changed since the run in {out} {said} (the same size, other contents)" \
                in err[0], err
            path.write_bytes(kept)  # put back (its time changed again): done
            assert main(run) == 0
        for p in folder.iterdir():  # every frame touched, its bytes kept
            os.utime(p, ns=(p.stat().st_atime_ns, p.stat().st_mtime_ns + 10**9))
        assert main(run) == 0
    _without_sizes(tmp_path / "one", kept=("mtime_ns", "digest"), state_kept=("key_contents",))
    _same_size_other_frame(folder / "f2.bmp", folder / "f4.bmp")
    assert main(["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "one")]) == 0


def test_a_frame_written_again_after_it_was_labelled_is_refused_on_resume(tmp_path, capsys):
    """A folder's frame written again (re-extracted, edited) after a run from one label image labelled it: the run
    again is refused naming the file and its sizes then and now; before, it said "all frames already done" (or went
    on from the old frames' carry) and kept labels of frames that are no longer there. The key frame too. Its file
    put back, the run is done again; a run begun before the sizes were kept resumes unchecked."""
    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=5)
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main(run) == 0
    for name, said in (("f2.png", "labelled it ("), ("f0.png", "labelled from it (")):
        _refused_while_written_again(run, folder / name, said, capsys)
        assert "already done" in capsys.readouterr().out
    _without_sizes(out)
    _written_again(folder / "f2.png")
    assert main(run) == 0


def test_a_key_frames_run_refuses_a_frame_or_key_frame_written_again(tmp_path, capsys):
    """A run from a folder of key frames: a frame between them, or a key frame it was labelled from, written again
    since is refused on the run again, naming the file; put back, the run is done."""
    from _runs import key_frames_of

    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=6)
    keys = key_frames_of(key, tmp_path / "keys", positions=(0, 5))
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(keys), "--out", str(out)]
    assert main(run) == 0
    for name, said in (("f3.png", "labelled it ("), ("f5.png", "labelled from it (")):
        _refused_while_written_again(run, folder / name, said, capsys)


def test_a_key_frame_written_again_is_refused_before_the_run_forgets_a_stretch(tmp_path, capsys):
    """A key-frames run whose labels folder changed a key frame (its stretches to be labelled again) while another
    key frame's file was written again: refused before anything is written, so that the file put back, the run goes
    on (the stretches' steps were not cut from steps.jsonl while run.json still counted them)."""
    import cv2
    from _runs import key_frames_of

    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=6)
    keys = key_frames_of(key, tmp_path / "keys", positions=(0, 3, 5))
    out = tmp_path / "out"
    run = ["run", str(folder), "--labels", str(keys), "--out", str(out)]
    assert main(run) == 0
    labels = cv2.imread(str(keys / "f5.png"), cv2.IMREAD_UNCHANGED)
    labels[:8] = 1 - labels[:8].clip(0, 1)
    cv2.imwrite(str(keys / "f5.png"), labels)
    _refused_while_written_again(run, folder / "f0.png", "labelled from it (", capsys)


def test_a_truth_map_written_again_since_it_was_scored_is_refused_on_resume(tmp_path, capsys):
    """A truth map of a frame the run scored, written again since (corrected, or another clip's): the run again went
    on, or said "all frames already done", with run.json's running error mixing scores against the old truth and the
    new. Each scored line keeps the digest of its truth map (``truth_digest``): refused naming the map, a run from one
    label image and from key frames alike; put back, or saved again with the same labels, done; removed, named as
    missing."""
    import json

    from _runs import key_frames_of

    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=6)
    truth = tmp_path / "truth"
    truth.mkdir()
    for p in folder.glob("*.png"):
        (truth / p.name).write_bytes(key.read_bytes())
    keys = key_frames_of(key, tmp_path / "keys", positions=(0, 5))
    for labels, out in ((key, tmp_path / "one"), (keys, tmp_path / "keyed")):
        run = ["run", str(folder), "--labels", str(labels), "--out", str(out), "--truth", str(truth)]
        assert main(run) == 0
        lines = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
        assert all(isinstance(s["truth_digest"], str) for s in lines), lines
        from pcreg.runs.edited import file_digest  # the digest of the file's bytes, as first kept: still read

        text = (out / "steps.jsonl").read_text()
        (out / "steps.jsonl").write_text("".join(json.dumps({**s, "truth_digest": file_digest(truth / s["name"])}) + "\n"
                                                 for s in lines))
        assert main(run) == 0
        (out / "steps.jsonl").write_text(text)
        path = truth / "f2.png"
        kept = path.read_bytes()
        cv2.imwrite(str(path), 1 - cv2.imread(str(key), cv2.IMREAD_UNCHANGED))
        capsys.readouterr()
        assert main(run) == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and f"{path}: changed since the run in {out} scored f2.png against it" in err[0], err
        path.write_bytes(kept)
        assert main(run) == 0
        cv2.imwrite(str(path), cv2.imread(str(key), cv2.IMREAD_UNCHANGED), [cv2.IMWRITE_PNG_COMPRESSION, 0])
        assert path.read_bytes() != kept and main(run) == 0  # the same labels saved again: the same truth
        path.unlink()
        capsys.readouterr()
        assert main(run) == 2 and f"{path}: no truth labels for frame f2.png" in one_line_errors(capsys)[0]
        path.write_bytes(kept)


def test_a_resumed_run_reads_each_truth_map_once(tmp_path, monkeypatch):
    """A resumed ``--truth`` run over a folder decoded each truth map twice before its first step: once to check
    every map, once for the digest its scored line keeps. The check keeps the digests it computes."""
    import pcreg.runs.inputs as inputs

    folder, key = drifting_frames(tmp_path / "frames", (48, 64), n=6)
    truth = tmp_path / "truth"
    truth.mkdir()
    for p in folder.glob("*.png"):
        (truth / p.name).write_bytes(key.read_bytes())
    run = ["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "out"), "--truth", str(truth)]
    assert main(run + ["--stop", "3"]) == 0
    read, seen = inputs.read_labels, []
    monkeypatch.setattr(inputs, "read_labels", lambda f, *a: seen.append(f.name) or read(f, *a))
    assert main(run) == 0
    frames = sorted(p.name for p in folder.glob("f*.png"))
    assert seen == [key.name, *frames, "f3.png", "f4.png", "f5.png"], seen  # the frames scored now read again then
