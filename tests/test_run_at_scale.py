"""What a run of hours of video costs beyond its steps: the checks before its first step and its closing lines,
each the same as before and cheaper."""

from __future__ import annotations

from pathlib import Path

from pcreg.cli import main
from _runs import drifting_frames


def test_inputs_resolved_folder_by_folder_are_resolved_as_one_by_one(tmp_path):
    """The check that no output overwrites an input resolves each frame's folder once (an hour's frames took seconds
    one by one): the same paths as each resolved alone, links to files and to folders, missing names, '..' included."""
    from pcreg.formats import resolved
    from pcreg.runs.inputs import _resolved_all

    (tmp_path / "a" / "b").mkdir(parents=True)
    (tmp_path / "a" / "f.png").write_bytes(b"x")
    (tmp_path / "a" / "b" / "g.png").write_bytes(b"x")
    (tmp_path / "link.png").symlink_to(tmp_path / "a" / "b" / "g.png")
    (tmp_path / "dir").symlink_to(tmp_path / "a" / "b")
    (tmp_path / "dangling.png").symlink_to(tmp_path / "nowhere.png")
    paths = [tmp_path / "a" / "f.png", tmp_path / "link.png", tmp_path / "dir" / "g.png", tmp_path / "dir" / ".." / "f.png",
             tmp_path / "a" / "missing.png", tmp_path / "dangling.png", tmp_path / "dir" / "..", tmp_path / "a" / ".",
             Path("relative.png")]
    assert _resolved_all(paths) == [str(resolved(p)) for p in paths]


def test_the_closing_lines_keep_of_each_step_only_what_they_read(tmp_path, monkeypatch):
    """The suggestions and the closing lines read a few fields of each step: only those are kept while they are
    made (an hour's steps kept whole took about half a GB), with the same lines said."""
    import pcreg.runs.summary as summary
    from pcreg.runs.files import SUMMARY_FIELDS

    folder, key = drifting_frames(tmp_path / "frames", n=4)
    seen = []
    real = summary.predicted_summary

    def kept(steps, *args, **kwargs):
        seen.extend(steps.values())
        return real(steps, *args, **kwargs)

    monkeypatch.setattr(summary, "predicted_summary", kept)
    assert main(["run", str(folder), "--labels", str(key), "--out", str(tmp_path / "out"), "--suggest", "1"]) == 0
    assert seen and all(set(s) <= set(SUMMARY_FIELDS) and "predicted_error" in s for s in seen), seen[0]
    assert (tmp_path / "out" / "suggest.txt").read_text().count("\n") == 1
