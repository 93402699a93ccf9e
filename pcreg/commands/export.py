"""Write a ``pcreg run`` output's labels as an archive an annotation tool imports as it is.

``--format cvat-mask``: CVAT's "Segmentation mask 1.1" (the Pascal VOC segmentation layout; see
:mod:`pcreg.export`), one mask per labelled frame, the key frame included, named as the frames are.
Unknown pixels, and with ``--min-confidence P`` every pixel whose confidence (``OUT/confidence/``) is
below P, are left unlabelled in the tool. The archive is written as the frames are read and checked, one
frame in memory at a time, into a temporary file that takes the place of ``OUT/export-cvat-mask.zip`` (or
``--to FILE``) once every frame is in: a refused frame or a stop leaves nothing there.

A run whose video skips frames by its times (run.json's ``gaps``) is exported with its frames numbered by count,
as CVAT numbers a video's frames; a note on stderr says so once (where, and that the run's frame N is not frame N
of the file's timeline). The archive is the layout CVAT imports, with no readme or manifest to say it in. What else
the run met reading its frames (run.json's ``notes``: transparent pixels, a turn to interlaced) is said on stderr too.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._common import arg_float


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..export import FORMATS

    p.add_argument("folder", metavar="OUT", help="a pcreg run output folder (its run.json, steps.jsonl and NAME.png)")
    p.add_argument("--format", choices=FORMATS, default=FORMATS[0],
                   help="cvat-mask (default): CVAT's Segmentation mask 1.1 zip, the Pascal VOC segmentation layout")
    p.add_argument("--to", metavar="FILE.zip", default=None, help="the archive (default OUT/export-FORMAT.zip)")
    p.add_argument("--min-confidence", type=arg_float(0, 1), default=None, metavar="P",
                   help="leave unlabelled every pixel whose confidence is below P (needs a run made with --confidence; "
                        "the key frames' labels are kept)")
    p.add_argument("--force", action="store_true", help="overwrite the archive")


def run(args: argparse.Namespace) -> int:
    from .._runner import ignore_signals, progress
    from ..classes.table import listed_name
    from ..export import cvat_table, default_name, labelled_frames, read_run, write_cvat_mask_archive
    from ..formats import resolved
    from ..outputs import check_output
    from ..runs.state import read_state, run_inputs, unfinished_note
    from ..validation import listed

    from ..errors import OutputError

    run_labels = read_run(args.folder)
    table = run_labels.table  # the run's class table: its labelmap.txt, colours and names
    default = Path(args.folder) / default_name(args.format)
    # the run's own inputs (its key labels, a CVAT export among them) are no file to write over, --force or not
    inputs = run_inputs(read_state(Path(args.folder))["run"])
    dest = check_output(Path(args.to) if args.to is not None else default, force=args.force, inputs=inputs)
    folder, to = resolved(args.folder), resolved(dest)
    if to != resolved(default) and folder in to.parents and dest.suffix.lower() != ".zip":
        raise OutputError(f"--to {dest}: inside the run's own folder and not a .zip; the archive would replace one "
                          "of the run's files (choose a .zip name or another folder)")
    # a file of a folder the run reads (a frame, a key frame's labels, a truth file), which a run's output folder
    # inside it (checked above) is not: the archive would take its place, --force or not
    read_from = next((p for p in inputs if folder not in to.parents and to.is_file() and Path(p).is_dir()
                      and resolved(p) in to.parents), None)
    if read_from is not None:
        raise OutputError(f"--to {dest}: a file of the folder {read_from} the run reads; the archive would replace "
                          "it (choose another name or folder)")
    if dest.suffix.lower() != ".zip":  # --force took an image's name (another run's frame), and made it a zip
        raise OutputError(f"--to {dest}: not a .zip name; the archive CVAT imports is a .zip (name it NAME.zip)")
    # written as the frames are read and checked, in a temporary file that takes dest's place once all are;
    # a bar on a terminal: a run of hours of video takes minutes to export
    with progress(labelled_frames(run_labels, args.min_confidence), total=len(run_labels.names),
                  desc="frames", disable=None) as frames:
        counts = write_cvat_mask_archive(dest, frames, table)
    ignore_signals()  # the archive is whole: interrupted from here, the command would say nothing was written
    shown = [f"{listed_name(c.name)} in {counts[c.name]}" for c in table.known if counts[c.name]]
    absent = [listed_name(c.name) for c in table.known if not counts[c.name]]
    none = listed(absent) if len(absent) <= 3 else f"{len(absent)} others"
    print(f"wrote {dest}: {len(run_labels.names)} frame(s) (labels {listed(shown)}"
          f"{f'; {none} in none' if absent else ''}; unknown left unlabelled in {counts[table.unknown_class.name]})")
    for was, now in zip(table.classes, cvat_table(table).classes):  # the archive's background is black
        if was.colour == now.colour:
            continue
        said = (f"the unknown class {listed_name(was.name)} is {was.colour} in the run's table and black in the archive, "
                "CVAT's background: its pixels are left unlabelled there" if was.id == table.unknown else
                f"the class {listed_name(was.name)} is black in the run's table, CVAT's background, and {now.colour} in "
                f"the archive: its pixels go to the task's label {listed_name(was.name)}, CVAT matching labels by name")
        sys.stderr.write(f"pcreg: note: {said}\n")
    names = [listed_name(c.name) for c in table.known]
    print(f"CVAT: a task with the {len(names)} labels {listed(names)} of its labelmap.txt over the same frames; "
          "Upload annotations, format Segmentation mask 1.1")
    note = unfinished_note(Path(args.folder), len(run_labels.names), run_labels.chosen)
    if note:
        sys.stderr.write(f"pcreg: note: {note}\n")
    # where the video skips frames by its times (the run's frame N is not the file's), frames that decode with errors
    # (labelled from concealed pictures), what else reading the frames met (transparent pixels, a turn to interlaced)
    for line in run_labels.said():
        sys.stderr.write(f"pcreg: note: {line}\n")
    return 0
