"""Soak of ``pcreg run``: memory, time and bytes written per frame over a long stream, and a killed run
that resumes to exactly the uninterrupted run's outputs.

The stream: a synthetic clip of ``n // 10 + 1`` distinct frames (:func:`pcreg.synthetic`), played
forwards and backwards until ``n`` frames are written, each with its own seeded +-1 dither so that no
two frame files are alike (a cache keyed by content would still grow). Played back and forth, the
first and the last tenth of the stream show the same frames of the clip, so a change of time per frame
between them is the program's, not the content's. (One synthetic clip of 2,000 frames moves the camera
forwards all along: by its end the scene is zoomed 3.4x from the key frame, and registration work
changes with it.) Truth labels go with every frame (``--truth``), so the scoring path runs too.

``pcreg run`` runs as a subprocess and is sampled from outside every ``--interval`` s: its resident
memory (VmRSS, and the peak VmHWM) and CPU time (``/proc/PID/status`` and ``stat``), the bytes it
passed to ``write()`` (``wchar`` in ``/proc/PID/io``), how many frames ``run.json`` counts and its
size. Time per frame is the difference of consecutive label PNGs' modification times (the whole loop:
reading, the step, writing); the step's own time comes from ``steps.jsonl``.

Then the same command runs again into a second folder and is killed (SIGKILL) once a frame chosen by
``--seed`` is committed; run again, it resumes. Every file of the two folders must then be the same:
the label PNGs and ``run.json`` byte for byte, ``steps.jsonl`` except its times (every frame is
registered to the key frame, so a step depends on the key frame and itself only).

    python tools/bench_soak.py --out out/bench [--frames 2000] [--size 320x240] [--seed 0]

Writes bench_soak.json, bench_soak.md and bench_soak.png (memory and ms per frame against the frame).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from benchlib import REPO_ROOT, checks_markdown, machine_info, write_report

#: Resident memory may grow at most this much from the warm frame to the end: a leak of one label map
#: (77 KB at 320x240) per frame would add 150 MB over 2,000 frames, many times this on a ~300 MB process.
TARGET_RSS_GROWTH = 0.05
#: The median time per frame of the last tenth within this fraction of the first tenth's (same frames of
#: the clip): work that grows with the frames done (a list scanned, a file rewritten whole) would
#: double it or more by the end; a loaded machine's noise stays within it over medians of 200 frames.
TARGET_TIME_DRIFT = 0.10
#: Bytes written per frame (run.json, a steps line, write() calls in all) in the last tenth at most this
#: much above the first tenth's: O(n) rewriting would make it about 10x at the end; the counters' growing
#: digits add a few bytes in ~3 KB.
TARGET_BYTES_DRIFT = 0.05
#: Frames before memory is measured against: imports, compiled kernels and allocator pools settle in
#: the first steps (the first takes seconds); 100 frames are 5% of the default stream.
WARM_FRAME = 100
STEP_TIME_FIELDS = ("times",)  # per-step stage times in steps.jsonl
REGISTRATION_TIME_FIELDS = ("seconds", "global_seconds")  # the registration's own clock in a step


def clip_index(i: int, distinct: int) -> int:
    """Frame of the clip shown at stream frame ``i``: forwards, then backwards, repeated."""
    period = 2 * (distinct - 1)
    r = i % period
    return r if r < distinct else period - r


def render_stream(folder: Path, n: int, *, size: tuple[int, int], preset: str, seed: int) -> dict:
    """Write ``folder/frames/fNNNNN.png``, ``folder/truth/fNNNNN.png`` and ``folder/key.png``; timings."""
    import cv2

    from pcreg.datasets import synthetic

    distinct = max(2, n // 10 + 1)
    t0 = time.perf_counter()
    clip = synthetic(preset, distinct, seed, width=size[0], height=size[1])
    t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    frames, truth = folder / "frames", folder / "truth"
    frames.mkdir(parents=True)
    truth.mkdir()
    digits = max(5, len(str(n - 1)))
    label_png = [cv2.imencode(".png", f.labels)[1].tobytes() for f in clip]
    for i in range(n):
        c = clip_index(i, distinct)
        dither = np.random.default_rng([seed, i]).integers(-1, 2, size=clip[c].image.shape, dtype=np.int16)
        img = np.clip(clip[c].image.astype(np.int16) + dither, 0, 255).astype(np.uint8)
        name = f"f{i:0{digits}d}.png"
        cv2.imwrite(str(frames / name), img[:, :, ::-1])
        (truth / name).write_bytes(label_png[c])
    (folder / "key.png").write_bytes(label_png[0])
    return {"distinct_frames": distinct, "render_seconds": t_render, "write_seconds": time.perf_counter() - t0,
            "names": [f"f{i:0{digits}d}" for i in range(n)], "clip": [clip_index(i, distinct) for i in range(n)]}


def pcreg_command(folder: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "pcreg.cli", "run", str(folder / "frames"), "--labels", str(folder / "key.png"),
            "--truth", str(folder / "truth"), "--out", str(out)]


def child_env() -> dict:
    """This checkout's pcreg first on the child's path, as benchlib puts it first on ours."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
    return env


def _done(state: Path) -> int:
    try:
        return int(json.loads(state.read_text())["done"])
    except (OSError, ValueError, KeyError, TypeError):
        return 0


def sample(pid: int, state: Path) -> dict | None:
    """One look at the process from outside; None once it is gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        stat = Path(f"/proc/{pid}/stat").read_text()
        io = Path(f"/proc/{pid}/io").read_text()
    except OSError:
        return None
    kb = {ln.split(":")[0]: int(ln.split()[1]) for ln in status.splitlines() if ln.startswith(("VmRSS", "VmHWM"))}
    if "VmRSS" not in kb:  # exited, not yet reaped: no memory left to measure
        return None
    fields = stat[stat.rindex(")") + 2:].split()
    ticks = os.sysconf("SC_CLK_TCK")
    wchar = next(int(ln.split()[1]) for ln in io.splitlines() if ln.startswith("wchar"))
    try:
        state_bytes = state.stat().st_size
    except OSError:
        state_bytes = None
    return {"t": time.monotonic(), "rss_mb": kb["VmRSS"] / 1024, "hwm_mb": kb.get("VmHWM", kb["VmRSS"]) / 1024,
            "cpu_s": (int(fields[11]) + int(fields[12])) / ticks, "wchar": wchar, "done": _done(state),
            "state_bytes": state_bytes, "load1": os.getloadavg()[0]}


def soak_run(folder: Path, out: Path, *, interval: float, logs: Path) -> dict:
    """Run ``pcreg run`` to the end, sampled every ``interval`` s."""
    with open(logs / "soak.out", "w") as so, open(logs / "soak.err", "w") as se:
        t0 = time.monotonic()
        p = subprocess.Popen(pcreg_command(folder, out), stdout=so, stderr=se, env=child_env())
        samples = []
        while p.poll() is None:
            s = sample(p.pid, out / "run.json")
            if s is not None:
                samples.append(s)
            try:
                p.wait(timeout=interval)
            except subprocess.TimeoutExpired:
                pass
    return {"returncode": p.returncode, "seconds": time.monotonic() - t0, "samples": samples,
            "stderr": (logs / "soak.err").read_text()[-2000:]}


def killed_and_resumed(folder: Path, out: Path, *, at: int, logs: Path) -> dict:
    """Kill ``pcreg run`` (SIGKILL) once ``at`` frames are committed, list what it left, run it again."""
    state = out / "run.json"
    with open(logs / "kill.err", "w") as se:
        p = subprocess.Popen(pcreg_command(folder, out), stdout=subprocess.DEVNULL, stderr=se, env=child_env())
        while p.poll() is None and _done(state) < at:
            try:
                p.wait(timeout=0.01)  # a frame takes tens of ms: the kill lands within the next frame or so
            except subprocess.TimeoutExpired:
                pass
        killed = p.poll() is None
        if killed:
            p.send_signal(signal.SIGKILL)
        p.wait()
    at_kill = _done(state)
    leftovers = sorted(f.name for f in out.iterdir() if f.name.endswith(".tmp"))
    again = subprocess.run(pcreg_command(folder, out), capture_output=True, text=True, env=child_env())
    return {"target_frame": at, "killed": killed, "returncode_killed": p.returncode, "done_at_kill": at_kill,
            "temporary_files_after_kill": leftovers, "returncode_resumed": again.returncode,
            "resumed_stdout": again.stdout.strip()[-500:], "resumed_stderr": again.stderr.strip()[-2000:]}


def _timeless(line: bytes) -> dict:
    step = json.loads(line)
    for k in STEP_TIME_FIELDS:
        step.pop(k, None)
    for k in REGISTRATION_TIME_FIELDS:
        (step.get("registration") or {}).pop(k, None)
    return step


def compare_outputs(a: Path, b: Path) -> dict:
    """Files of two run folders: label PNGs and run.json byte for byte, steps.jsonl without its times."""
    names_a = {f.name for f in a.iterdir() if f.name != ".pcreg.lock"}
    names_b = {f.name for f in b.iterdir() if f.name != ".pcreg.lock"}
    differ = []
    for name in sorted(names_a & names_b):
        x, y = (a / name).read_bytes(), (b / name).read_bytes()
        if name == "steps.jsonl":
            same = [_timeless(ln) for ln in x.splitlines()] == [_timeless(ln) for ln in y.splitlines()]
        else:
            same = x == y
        if not same:
            differ.append(name)
    return {"files": len(names_a | names_b), "only_uninterrupted": sorted(names_a - names_b),
            "only_resumed": sorted(names_b - names_a), "differ": differ,
            "identical": not differ and names_a == names_b}


def analyse(run: dict, out: Path, names: list[str], clip: list[int]) -> dict:
    """Per-frame series and the first/last-tenth comparisons."""
    n = len(names)
    steps = (out / "steps.jsonl").read_bytes().splitlines(keepends=True)
    line_bytes = [len(ln) for ln in steps]  # step of frame t is line t - 1
    step_ms = [1e3 * json.loads(ln)["times"]["total"] for ln in steps]
    mtimes = [(out / f"{name}.png").stat().st_mtime_ns for name in names]
    frame_ms = [(mtimes[t] - mtimes[t - 1]) / 1e6 for t in range(1, n)]  # frame t's whole loop, t = 1 .. n-1
    w = max(1, (n - 1) // 10)
    first, last = slice(0, w), slice(len(frame_ms) - w, len(frame_ms))  # steps of frames 1..w and n-w..n-1
    samples = run["samples"]
    warm = min(WARM_FRAME, max(1, n // 10))
    after = [s for s in samples if s["done"] >= warm]
    rss0 = after[0]["rss_mb"] if after else float("nan")
    rss_max = max((s["rss_mb"] for s in after), default=float("nan"))
    rss_end = after[-1]["rss_mb"] if after else float("nan")

    def per_frame(key: str, lo: int, hi: int) -> float:
        """Change of a sampled counter per frame committed between ``lo`` and ``hi`` frames done."""
        inside = [s for s in samples if lo <= s["done"] <= hi]
        if len(inside) < 2 or inside[-1]["done"] == inside[0]["done"]:
            return float("nan")
        # from the moment the first count was reached to the moment the last was: after the last frame
        # the process still prints, closes and exits, which is no frame's work
        inside = inside[: next(i for i, s in enumerate(inside) if s["done"] == inside[-1]["done"]) + 1]
        return (inside[-1][key] - inside[0][key]) / (inside[-1]["done"] - inside[0]["done"])

    sizes = [(s["done"], s["state_bytes"]) for s in samples if s["state_bytes"]]
    state_first = [b for d, b in sizes if 1 < d <= w + 1]
    state_last = [b for d, b in sizes if d > n - w]
    def med(xs) -> float:
        return float(np.median(xs)) if len(xs) else float("nan")
    return {
        "frames": n, "window": w, "warm_frame": warm,
        "same_content_in_windows": sorted(clip[1:w + 1]) == sorted(clip[n - w:]),
        "rss_mb_at_warm": rss0, "rss_mb_max_after_warm": rss_max, "rss_mb_at_end": rss_end,
        "rss_growth": rss_max / rss0 - 1.0, "rss_growth_at_end": rss_end / rss0 - 1.0,
        "peak_hwm_mb": max((s["hwm_mb"] for s in samples), default=float("nan")),
        "frame_ms_first": med(frame_ms[first]), "frame_ms_last": med(frame_ms[last]),
        "step_ms_first": med(step_ms[first]), "step_ms_last": med(step_ms[last]),
        "cpu_ms_per_frame_first": 1e3 * per_frame("cpu_s", 2, w + 1),
        "cpu_ms_per_frame_last": 1e3 * per_frame("cpu_s", n - w, n),
        "write_bytes_per_frame_first": per_frame("wchar", 2, w + 1),
        "write_bytes_per_frame_last": per_frame("wchar", n - w, n),
        "state_bytes_first": med(state_first), "state_bytes_last": med(state_last),
        "state_bytes_min": min((b for _, b in sizes), default=None), "state_bytes_max": max((b for _, b in sizes), default=None),
        "step_line_bytes_first": med(line_bytes[first]), "step_line_bytes_last": med(line_bytes[last]),
        "load_first": med([s["load1"] for s in samples if 1 < s["done"] <= w + 1]),
        "load_last": med([s["load1"] for s in samples if s["done"] > n - w]),
        "series": {"frame_ms": frame_ms, "step_ms": step_ms, "step_line_bytes": line_bytes,
                   "samples": [{k: s[k] for k in ("done", "rss_mb", "hwm_mb", "cpu_s", "wchar", "state_bytes", "load1")}
                               for s in samples]},
    }


def _ratio(a: float, b: float) -> float:
    return a / b if b and np.isfinite(a) and np.isfinite(b) else float("nan")


def checks(report: dict) -> list[tuple[str, str, bool | None]]:
    a = report["soak"]
    rows = [
        (f"resident memory grows <= {100 * TARGET_RSS_GROWTH:g}% from frame {a['warm_frame']} to the end",
         f"{100 * a['rss_growth']:+.1f}% ({a['rss_mb_at_warm']:.0f} -> max {a['rss_mb_max_after_warm']:.0f} MB)",
         a["rss_growth"] <= TARGET_RSS_GROWTH),
    ]
    r = _ratio(a["frame_ms_last"], a["frame_ms_first"])
    rows.append((f"median ms per frame, last tenth within {100 * TARGET_TIME_DRIFT:g}% of the first",
                 f"{a['frame_ms_first']:.1f} -> {a['frame_ms_last']:.1f} ms ({r:.3f}x)",
                 abs(r - 1.0) <= TARGET_TIME_DRIFT if np.isfinite(r) else None))
    r = _ratio(a["cpu_ms_per_frame_last"], a["cpu_ms_per_frame_first"])
    rows.append((f"CPU ms per frame (the process's own; others' load moves it less), last tenth within "
                 f"{100 * TARGET_TIME_DRIFT:g}% of the first",
                 f"{a['cpu_ms_per_frame_first']:.1f} -> {a['cpu_ms_per_frame_last']:.1f} ms ({r:.3f}x)",
                 abs(r - 1.0) <= TARGET_TIME_DRIFT if np.isfinite(r) else None))
    for key, what in (("write_bytes_per_frame", "bytes written per frame (write() calls)"),
                      ("state_bytes", "run.json bytes (rewritten each frame)"),
                      ("step_line_bytes", "steps.jsonl bytes per frame")):
        r = _ratio(a[f"{key}_last"], a[f"{key}_first"])
        rows.append((f"{what}: last tenth <= {1 + TARGET_BYTES_DRIFT:g}x the first (O(1))",
                     f"{a[f'{key}_first']:.0f} -> {a[f'{key}_last']:.0f} ({r:.3f}x)",
                     r <= 1 + TARGET_BYTES_DRIFT if np.isfinite(r) else None))
    k = report.get("kill")
    if k:
        c = k["compare"]
        rows.append(("killed (SIGKILL) and resumed: every output file as the uninterrupted run's",
                     f"killed at {k['done_at_kill']} of {a['frames']} frames; {c['files']} files, "
                     f"{len(c['differ'])} differ, {len(c['only_uninterrupted']) + len(c['only_resumed'])} unmatched",
                     c["identical"] and k["returncode_resumed"] == 0 if k["killed"] else None))
    return rows


def render(report: dict) -> str:
    from pcreg.outputs import markdown_table

    a, r = report["soak"], report["stream"]
    lines = [f"### Soak of `pcreg run`: {a['frames']} frames at {r['size']} ({r['preset']}, "
             f"{r['distinct_frames']} distinct, played back and forth)\n",
             f"Rendering the clip took {r['render_seconds']:.1f} s, writing {a['frames']} frames and truth labels "
             f"{r['write_seconds']:.1f} s; the run {report['run_seconds']:.0f} s. First and last tenth = "
             f"{a['window']} frames each (same frames of the clip: {a['same_content_in_windows']}).\n",
             markdown_table(["measure", "first tenth", "last tenth"], [
                 ["ms per frame (label PNG mtimes)", a["frame_ms_first"], a["frame_ms_last"]],
                 ["ms per step (steps.jsonl)", a["step_ms_first"], a["step_ms_last"]],
                 ["CPU ms per frame", a["cpu_ms_per_frame_first"], a["cpu_ms_per_frame_last"]],
                 ["bytes written per frame", a["write_bytes_per_frame_first"], a["write_bytes_per_frame_last"]],
                 ["run.json bytes", a["state_bytes_first"], a["state_bytes_last"]],
                 ["steps.jsonl line bytes", a["step_line_bytes_first"], a["step_line_bytes_last"]],
                 ["load average (1 min)", a["load_first"], a["load_last"]],
             ], digits=1),
             f"Resident memory: {a['rss_mb_at_warm']:.1f} MB at frame {a['warm_frame']}, at most "
             f"{a['rss_mb_max_after_warm']:.1f} MB after, {a['rss_mb_at_end']:.1f} MB at the end "
             f"(peak VmHWM {a['peak_hwm_mb']:.1f} MB).\n"]
    k = report.get("kill")
    if k:
        lines.append(f"Kill and resume: the frame drawn was {k['target_frame']}; killed: {k['killed']} with "
                     f"{k['done_at_kill']} frames committed; temporary files left by the kill: "
                     f"{len(k['temporary_files_after_kill'])}; resumed run exit {k['returncode_resumed']}.\n")
    lines.append(checks_markdown(checks(report)))
    load = report["machine"].get("load_average"), report.get("load_average_at_end")
    lines.append(f"\nLoad average (1, 5, 15 min) at the start {load[0]} and at the end {load[1]}, on "
                 f"{report['machine']['cpu_count']} CPUs.\n")
    return "\n".join(lines)


def figure(report: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = report["soak"]["series"]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    done = [x["done"] for x in s["samples"]]
    ax1.plot(done, [x["rss_mb"] for x in s["samples"]], lw=1, label="VmRSS")
    ax1.plot(done, [x["hwm_mb"] for x in s["samples"]], lw=1, ls="--", label="VmHWM (peak)")
    ax1.axvline(report["soak"]["warm_frame"], color="grey", lw=0.8, ls=":")
    ax1.set_ylabel("MB")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    ms = np.asarray(s["frame_ms"])
    x = np.arange(1, len(ms) + 1)
    ax2.plot(x, ms, ".", ms=1.5, alpha=0.4, label="per frame (PNG mtimes)")
    k = max(1, report["soak"]["window"] // 4)
    if len(ms) >= k:
        rolling = [float(np.median(ms[max(0, i - k):i + 1])) for i in range(len(ms))]
        ax2.plot(x, rolling, lw=1.2, color="black", label=f"running median of {k}")
    ax2.set_yscale("log")
    ax2.set_ylabel("ms per frame")
    load = ax2.twinx()  # the machine's load moves the wall time: shown beside it
    load.plot(done, [x.get("load1", np.nan) for x in s["samples"]], lw=0.8, color="tab:red", alpha=0.6)
    load.set_ylabel("load average (1 min)", color="tab:red", fontsize=8)
    ax2.set_xlabel("frame")
    ax2.legend(fontsize=8)
    ax2.grid(alpha=0.3)
    fig.suptitle(f"pcreg run, {report['soak']['frames']} frames at {report['stream']['size']}", fontsize=10)
    fig.tight_layout()
    return fig


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/bench", help="folder for bench_soak.json/.md/.png (default out/bench)")
    p.add_argument("--frames", type=int, default=2000, help="frames in the stream (default 2000; at least 10)")
    p.add_argument("--size", default="320x240", help="frame size WxH (default 320x240)")
    p.add_argument("--preset", default="syn1a", help="synthetic clip (default syn1a)")
    p.add_argument("--seed", type=int, default=0, help="the clip, the dither and the frame the kill lands on")
    p.add_argument("--interval", type=float, default=0.1,
                   help="seconds between samples (default 0.1: a few per frame, negligible cost)")
    p.add_argument("--no-kill", action="store_true", help="skip the kill-and-resume run")
    p.add_argument("--keep", metavar="DIR", default=None, help="render and run in DIR and keep it (default: a temporary folder)")
    args = p.parse_args(argv)
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        print(f"--size must be WxH, got {args.size!r}", file=sys.stderr)
        return 2
    if args.frames < 10 or w < 32 or h < 32 or not args.interval > 0:
        print("--frames must be at least 10, --size at least 32x32 and --interval above 0", file=sys.stderr)
        return 2

    report = {"machine": machine_info(),
              "targets": {"rss_growth": TARGET_RSS_GROWTH, "time_drift": TARGET_TIME_DRIFT,
                          "bytes_drift": TARGET_BYTES_DRIFT, "warm_frame": WARM_FRAME}}
    with tempfile.TemporaryDirectory(prefix="pcreg-soak-") as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        print(f"rendering {args.frames} frames into {work} ...", file=sys.stderr, flush=True)
        stream = render_stream(work, args.frames, size=(w, h), preset=args.preset, seed=args.seed)
        names, clip = stream.pop("names"), stream.pop("clip")
        report["stream"] = {**stream, "size": f"{w}x{h}", "preset": args.preset, "seed": args.seed}
        print("soak run ...", file=sys.stderr, flush=True)
        run = soak_run(work, work / "uninterrupted", interval=args.interval, logs=work)
        if run["returncode"] != 0:
            print(f"pcreg run failed (exit {run['returncode']}):\n{run['stderr']}", file=sys.stderr)
            return 1
        report["run_seconds"] = run["seconds"]
        report["soak"] = analyse(run, work / "uninterrupted", names, clip)
        if not args.no_kill:
            at = int(np.random.default_rng(args.seed).integers(2, args.frames - max(1, args.frames // 10)))
            print(f"killed at frame {at}, resumed ...", file=sys.stderr, flush=True)
            kill = killed_and_resumed(work, work / "resumed", at=at, logs=work)
            kill["compare"] = compare_outputs(work / "uninterrupted", work / "resumed")
            report["kill"] = kill
    report["load_average_at_end"] = machine_info()["load_average"]
    md = render(report)
    write_report(args.out, "bench_soak", report, md, figure(report))
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
