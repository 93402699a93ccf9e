"""Open rerun recordings (.rrd) in the viewer or in a browser, render a screenshot of one without a display,
show an evaluation's output folder (its tables, figures and checks beside its recording) in a browser, or
review a pcreg run output (its frames with their labels) in a browser or as a video.

Every recording is shown with the blueprint of its kind built from what it holds (no empty view);
several recordings (``pcreg view A.rrd B.rrd``) are merged into one comparison, each under its file
name, the same view of each side by side and their series in one plot (:mod:`pcreg.recording.staging`).

``pcreg view FILE.rrd`` starts the native viewer (the ``rerun`` program that comes with rerun-sdk).
``pcreg view FILE.rrd --web`` serves rerun's web viewer (its assets are inside rerun-sdk; nothing is
downloaded) and the recording over gRPC, both on 127.0.0.1 unless ``--bind`` says otherwise, prints the
URL to open and serves until Ctrl-C: no display and no GPU needed on the machine (over SSH, forward
both ports, e.g. ``ssh -L 9090:localhost:9090 -L 9876:localhost:9876 HOST``).
``pcreg view OUT_DIR --web`` serves the report page of an evaluation's output folder (``evaluate
sequence|rotation|stream|classification --out OUT_DIR``) on the same ports: its tables (from
results.json), figures and checks, with the run's recording (the .rrd file its ``--record`` wrote in OUT_DIR, or the
recordings given after it) embedded beside them; choosing a row of a table moves the recording to that row's frame.
``pcreg view FILE.rrd --screenshot OUT.png [--time frame=N] [--view NAME]`` renders the recording
headless (:func:`pcreg.recording.viewer.screenshot`) and saves the picture.
``pcreg view RUN_OUT --web`` (a ``pcreg run`` output, recognised by its run.json) serves the review page
(:mod:`pcreg.recording.review`): every frame of the run with its labels drawn over it, the unsure
labels hatched, the key frames marked, the predicted error per frame and the suggested frames.
``pcreg view RUN_OUT --overlay FILE.mp4`` writes the same frames as a video of their size, each with its legend drawn
in (:func:`pcreg.review.write_overlay_video`, :mod:`pcreg.legend`).
A run whose video skips frames by its times (run.json's ``gaps``) is said on stderr, on the page and in the
overlay video's comment: its frames are numbered by count, so the run's frame N is not frame N of the file. What
else the run met reading its frames (run.json's ``notes``: transparent pixels, a turn to interlaced) is said on
stderr and on the page, each kind once.

The viewer processes themselves are managed in :mod:`pcreg.recording.viewer` and
:mod:`pcreg.recording.report`.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from .._signals import ignore_signals
from ..errors import InputError, OutputError


#: The ports ``--web`` serves on when none is given, each taken when free; when another server holds one (a second
#: user of the machine, another ``pcreg view``) any free port is taken instead, and the URL printed names it.
WEB_PORT, GRPC_PORT = 9090, 9876


def _choose_ports(args: argparse.Namespace, *, grpc: bool = True) -> None:
    """``args.web_port`` and ``args.grpc_port`` (with ``grpc``) not given: :data:`WEB_PORT` and :data:`GRPC_PORT`
    when free on ``--bind``, else 0 (any free port), said on stderr. A port given is kept, and refused later
    when in use."""
    from ..recording.viewer import check_bind, port_free

    probe = check_bind(args.bind) if args.web else None
    for attr, default, flag in (("web_port", WEB_PORT, "--web-port"), ("grpc_port", GRPC_PORT, "--grpc-port")):
        if getattr(args, attr) is not None or (attr == "grpc_port" and not grpc):
            continue
        taken = probe is not None and not port_free(probe, default)
        setattr(args, attr, 0 if taken else default)
        if taken:  # said once serving (:func:`_note_serving`): bad input before it is one line
            args.port_notes = [*getattr(args, "port_notes", []), f"pcreg: note: port {default} is in use on {args.bind}; "
                               f"serving on a free port instead ({flag} chooses one)\n"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recordings", metavar="FILE.rrd|OUT_DIR", nargs="+",
                        help="the recording to show; several are shown side by side (a comparison); or an "
                             "evaluation's output folder, shown with --web (its recording: the .rrd file the run "
                             "recorded in it, or the recordings given after it); or a pcreg run output, reviewed with --web or "
                             "written with --overlay FILE.mp4")
    parser.add_argument("--web", action="store_true",
                        help="serve the web viewer (for OUT_DIR: the report page, or a run's review page) and print its URL "
                             "instead of opening a window")
    parser.add_argument("--bind", metavar="ADDRESS", default="127.0.0.1",
                        help="address the web viewer and its data server listen on (default 127.0.0.1: this machine only)")
    parser.add_argument("--web-port", type=_port, default=None,
                        help=f"web page's HTTP port (default {WEB_PORT}, or any free port when another server holds it; "
                             "0: any free port)")
    parser.add_argument("--grpc-port", type=_port, default=None,
                        help=f"recording server's port (default {GRPC_PORT}, or any free port when another server "
                             "holds it; 0: any free port)")
    parser.add_argument("--screenshot", metavar="OUT.png", help="render to this PNG headless instead of opening a window")
    parser.add_argument("--time", metavar="TIMELINE=N", help="put the time cursor here before the screenshot, e.g. frame=3")
    parser.add_argument("--view", metavar="NAME", help="screenshot only the view with this name (e.g. Registration)")
    from ._common import arg_float, arg_window_size

    parser.add_argument("--size", type=arg_window_size, metavar="WxH", default="1600x900", help="headless window size in points (default 1600x900)")
    parser.add_argument("--viewer", metavar="PATH", help="the rerun program (default: the one installed with rerun-sdk)")
    parser.add_argument("--timeout", type=arg_float(0, 86400, lo_open=True), default=60.0, help="seconds to wait for the viewer (default 60)")
    parser.add_argument("--overlay", metavar="FILE.mp4",
                        help="for a pcreg run output: write its frames with their labels drawn over them as a video, "
                             "each with a legend of its name and classes")
    parser.add_argument("--fps", type=arg_float(0.001, 1000), default=None,
                        help="frames per second of the --overlay video, 0.001..1000 (default: a video's own, 10 for a "
                             "folder of frames)")
    parser.add_argument("--force", action="store_true", help="overwrite OUT.png (or the --overlay video)")


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"a port is 0..65535, got {value}")
    return value


def _parse_time(text: str | None) -> tuple[str, int] | None:
    if not text:
        return None
    name, sep, value = text.partition("=")
    try:
        if not sep or not name:
            raise ValueError
        n = int(value)
    except ValueError:
        raise InputError(f"--time must look like TIMELINE=N (e.g. frame=3), got {text!r}") from None
    if not -(2**63) <= n < 2**63:  # rerun's sequence times are 64-bit integers
        raise InputError(f"--time {n} is out of range (a 64-bit integer)")
    return name.strip(), n


def run(args: argparse.Namespace) -> int:
    from ..outputs import check_output
    from ..recording import viewer as V
    from ..recording.readback import unfinished_note
    from ..recording.staging import stage
    from ..review import is_run
    from ..runs.state import no_run

    runs = [p for p in args.recordings if Path(p).is_dir() and is_run(p)]
    _choose_ports(args, grpc=not runs)  # a run's review page has no recording server
    if runs:
        return _review(args, runs)
    if args.overlay:
        damaged = next((Path(p) / "run.json" for p in args.recordings if (Path(p) / "run.json").is_file()), None)
        if damaged is not None:  # a run's folder whose run.json is damaged: named, as the review names it
            raise InputError(f"{damaged}: unreadable (not a run.json that pcreg run wrote)")
        first = Path(args.recordings[0])
        raise InputError(no_run(first, ", which --overlay takes") if first.is_dir()
                         else f"{first}: not a folder; --overlay takes the output folder of pcreg run")
    folders = [p for p in args.recordings if Path(p).is_dir() or Path(p).name == "results.json"]
    if folders:
        return _report(args, folders)
    for r in args.recordings:
        if not Path(r).exists():
            raise InputError(f"{r}: no such file or folder")
        V.check_recording(r)
    if args.web and args.screenshot:
        raise InputError("--web serves the viewer to a browser; --screenshot renders without one: choose one")
    if args.screenshot is None and (args.time or args.view):
        raise InputError("--time and --view go with --screenshot")
    binary = V.find_viewer(args.viewer)
    native = args.screenshot is None and not args.web
    if native and sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise V.ViewerError("no display for the native viewer (DISPLAY and WAYLAND_DISPLAY are unset): "
                            "use --web to view it in a browser, or --screenshot OUT.png")
    out = None
    time_cursor = _parse_time(args.time)
    if args.screenshot is not None:
        out = check_output(args.screenshot, force=args.force, inputs=tuple(args.recordings))
        if out.suffix.lower() != ".png":
            raise OutputError(f"{out}: the screenshot is written as PNG; name it .png")
        _can_write(out)
    with tempfile.TemporaryDirectory(prefix="pcreg-view-") as tmp:
        staged = _stage(stage, args.recordings, Path(tmp))
        if out is not None and not staged.logged:  # the headless viewer would wait its whole --timeout for it
            raise InputError(f"{', '.join(args.recordings)}: nothing to draw (nothing logged, or the file ends "
                             "before its first data)")
        for note in filter(None, map(unfinished_note, args.recordings)):
            sys.stderr.write(f"pcreg: note: {note}\n")
        if out is not None:
            path = V.screenshot(staged.path, out, time_cursor=time_cursor, view=args.view, size=args.size,
                                viewer=binary, timeout=args.timeout)
            ignore_signals()  # the picture is written: interrupted from here, the command would say nothing was
            print(path)
            return 0
        if args.web:
            proc, url = V.serve_web(staged.path, bind=args.bind, web_port=args.web_port, grpc_port=args.grpc_port,
                                    viewer=binary, timeout=args.timeout)
            _note_serving(args)
            try:
                print(f"serving {', '.join(map(str, args.recordings))} on {args.bind} (Ctrl-C stops)")
                print(url, flush=True)
                proc.wait()
            except KeyboardInterrupt:
                return 130
            finally:
                V.stop(proc)
            if proc.returncode not in (0, -15):
                raise V.ViewerError(f"the web viewer stopped (exit code {proc.returncode})")
            return 0
        return subprocess.call([binary, str(staged.path)])


def _can_write(out: Path) -> None:
    """Refuse ``out`` before the viewer starts when its folder (or the nearest one of it that exists; the
    screenshot makes the rest) takes no file: a file is made there and removed (``os.access`` says yes to
    root even where nothing can be written, as in ``/proc``)."""
    folder = out.absolute().parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        with tempfile.NamedTemporaryFile(prefix=f".{out.name}.", suffix=".png", dir=folder):
            pass
    except OSError as exc:
        raise OutputError(f"cannot write {out}: no file can be made in {folder} ({exc.strerror or exc})") from None


def _stage(stage, recordings: list[str], tmp: Path):
    try:
        return stage(recordings, tmp / "view.rrd")
    except ValueError as exc:
        raise InputError(str(exc)) from None


def _note_serving(args: argparse.Namespace) -> None:
    """The notes of a server that serves: a default port in use (:func:`_choose_ports`), an address others reach."""
    sys.stderr.write("".join(getattr(args, "port_notes", [])))
    from ..recording.viewer import loopback

    if not loopback(args.bind):
        sys.stderr.write(f"pcreg: note: serving on {args.bind}: whoever can reach this machine there can read what it serves\n")


def _report(args: argparse.Namespace, folders: list[str]) -> int:
    """``pcreg view OUT_DIR [REC.rrd ...] --web``: the report page of an output folder beside its recording."""
    from ..experiments.reports.page import load_report, page_data
    from ..recording import viewer as V
    from ..recording.readback import unfinished_note
    from ..recording.report import ReportServer
    from ..recording.staging import stage

    if len(folders) > 1:
        raise InputError(f"one output folder at a time (got {', '.join(folders)})")
    folder = Path(folders[0])
    if folder.name == "results.json" and not folder.is_dir():
        folder = folder.parent
    if args.screenshot or args.time or args.view:
        raise InputError(f"{folder}: an output folder is shown with --web; --screenshot, --time and --view take a "
                         "recording (.rrd)")
    report = load_report(folder)
    data = page_data(report)
    recordings = [r for r in args.recordings if r != folders[0]] or [str(p) for p in report.recordings]
    applications = {}
    for r in recordings:
        if not Path(r).exists():
            raise InputError(f"{r}: no such file or folder")
        applications[r] = V.check_recording(r)[0]
    if not args.web:
        raise InputError(f"{folder}: an output folder is shown in a browser: add --web"
                         + (" (or view its recording: pcreg view " + " ".join(recordings) + ")" if recordings else ""))
    for r, application in applications.items():
        other = _other_recording(r, application, report.experiment)
        if other:  # said on the page too: its tables and the recording's frames do not go together
            sys.stderr.write(f"pcreg: note: {other}\n")
            data["notes"] = [other, *data["notes"]]
    binary = V.find_viewer(args.viewer) if recordings else None
    with tempfile.TemporaryDirectory(prefix="pcreg-view-") as tmp:
        staged = _stage(stage, recordings, Path(tmp)) if recordings else None
        for note in filter(None, map(unfinished_note, recordings)):  # as for a recording viewed alone
            sys.stderr.write(f"pcreg: note: {note}\n")
        server = ReportServer(folder, data, recording=None if staged is None else staged.path, bind=args.bind,
                              web_port=args.web_port, grpc_port=args.grpc_port, viewer=binary, timeout=args.timeout)
        with server:
            _note_serving(args)
            what = f"{folder}" + (f" with {', '.join(map(str, recordings))}" if recordings else " (no recording in it)")
            try:
                print(f"serving the report of {what} on {args.bind} (Ctrl-C stops)")
                print(server.url, flush=True)
                server.wait()
            except KeyboardInterrupt:
                return 130
    return 0


def _other_recording(path: str, application: str, experiment: str) -> str | None:
    """What to say of a recording shown beside the report of ``pcreg evaluate EXPERIMENT`` that is not one such
    evaluation wrote (another program's, ``application`` its id, or another pcreg command's), or None."""
    from ..recording.readback import read_kind

    if application != "pcreg":
        return (f"{path}: a recording of {application!r}, not of pcreg evaluate {experiment}: the report's frames and "
                "tables are not its")
    try:
        kind = read_kind(path)
    except (ValueError, RuntimeError):  # rerun's reader, of a file cut short (said as such): its kind not told
        kind = None
    if kind is not None and kind != experiment:  # (a recording without its kind, of an earlier pcreg: not told)
        return (f"{path}: a pcreg recording of kind {kind!r}, not of pcreg evaluate {experiment}: the report's frames "
                "and tables are not its")
    return None


def _review_note(folder: Path, review, *, web: bool) -> str | None:
    """What is said of an unfinished run (:func:`~pcreg.runs.state.unfinished_note`) over every frame it labelled, as
    the export counts them, and where the review (its frames in order from the first) stops short of them: a run from
    key frames stopped between its stretches has labelled frames after one it has not labelled yet. The ``web`` page
    shows what the run labels later when reloaded; the overlay video is written once."""
    from ..runs.state import read_state, run_frames, unfinished_note

    state, shown = read_state(folder), len(review.names)
    labelled = len(run_frames(state, folder)[1]) if "stretches" in state else shown  # read_review checked both
    later = "reload the page to see what it labels later" if web else "what it labels later is not shown"
    note = unfinished_note(folder, labelled, review.chosen, later=later)
    if labelled <= shown:
        return note
    short = (f"the review shows the {shown} frame(s) labelled from the first frame on, up to the first not labelled yet, "
             f"not the {labelled - shown} labelled after it (pcreg export has them all)")
    return f"{note}; {short}" if note else short


def _review(args: argparse.Namespace, runs: list[str]) -> int:
    """``pcreg view RUN_OUT --web`` (the review page) or ``--overlay FILE.mp4`` (the same frames as a video)."""
    from ..outputs import check_output
    from ..recording.review import ReviewServer
    from ..review import read_review, write_overlay_video

    if len(args.recordings) > 1:
        raise InputError(f"one run output folder at a time (got {', '.join(args.recordings)})")
    folder = Path(runs[0])
    if args.screenshot or args.time or args.view:
        raise InputError(f"{folder}: a run's output is shown with --web or written with --overlay FILE.mp4; "
                         "--screenshot, --time and --view take a recording (.rrd)")
    if args.web and args.overlay:
        raise InputError("--web serves the review page; --overlay writes a video: choose one")
    if not (args.web or args.overlay):
        raise InputError(f"{folder}: a run's output is reviewed in a browser (add --web) or as a video "
                         "(--overlay FILE.mp4)")
    if args.overlay:
        out = check_output(args.overlay, force=args.force)
        if out.suffix.lower() != ".mp4":
            raise OutputError(f"{out}: the overlay is written as an MP4 video; name it .mp4")
    review = read_review(folder)
    if not review.names:  # a run from key frames stopped before it labelled its first frame
        raise InputError(f"{folder}: holds no frame labelled from the run's first frame on: nothing to review yet "
                         "(an unfinished run: the same pcreg run command goes on from where it stopped)")
    if args.overlay:  # the run's video, which the overlay is drawn from, is no file to write over, --force or not
        check_output(out, force=args.force, inputs=(review.source,))
    note = _review_note(folder, review, web=bool(args.web))
    if note:
        sys.stderr.write(f"pcreg: note: {note}\n")
    # where the video skips frames by its times (the run's frame N is not the file's), frames that decode with errors
    # (labelled from concealed pictures), what else reading the frames met (transparent pixels, a turn to interlaced);
    # said once the video is written (a refused one says one line, its refusal), or before the page is served
    said = [f"pcreg: note: {line}\n" for line in review.said()]
    if args.overlay:
        n = write_overlay_video(review, out, fps=args.fps, note=lambda line: said.append(f"pcreg: note: {line}\n"))
        ignore_signals()  # the video is written: interrupted from here, the command would say nothing was
        sys.stderr.write("".join(said))
        print(f"wrote {out}: {n} frame(s) of {folder} with their labels")
        return 0
    sys.stderr.write("".join(said))
    with ReviewServer(review, bind=args.bind, web_port=args.web_port) as server:
        _note_serving(args)
        try:
            n = len(review.names)
            print(f"serving the review of {folder} ({n} frame{'' if n == 1 else 's'} of {review.source}) on {args.bind} "
                  "(Ctrl-C stops)")
            print(server.url, flush=True)
            server.wait()
        except KeyboardInterrupt:
            return 130
    return 0
