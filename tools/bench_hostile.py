"""How fast, and in how much memory, pcreg refuses hostile input; how fast an interrupted run stops.

Each case runs the real command line as a subprocess (``python -m pcreg.cli ...``) and records its exit
code, stderr lines, wall time and peak memory (``wait4``'s ``ru_maxrss``), median of ``--repeats``.
A missing file is the baseline: the cost of starting Python and importing pcreg. The targets: exit 2,
one stderr line, within 2 s and 200 MB more than the baseline; an interrupted ``--workers 2`` run
exits 130 within 5 s with no worker process left.
"""

from __future__ import annotations

import argparse
import os
import signal
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

from benchlib import REPO_ROOT, SHARED_DATA, checks_markdown, machine_info, write_report

import numpy as np

PCREG = [sys.executable, "-m", "pcreg.cli"]


def _png(w: int, h: int) -> bytes:
    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    body = zlib.compress((b"\x00" + b"\x00" * min(w * 3, 1 << 20)) * 64, 9)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", body) + chunk(b"IEND", b""))


def _run_rss(args: list[str]) -> dict:
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    with tempfile.TemporaryFile() as eo:
        t0 = time.perf_counter()
        p = subprocess.Popen([*PCREG, *args], stdout=subprocess.DEVNULL, stderr=eo, env=env)
        _, status, usage = os.wait4(p.pid, 0)
        seconds = time.perf_counter() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
        eo.seek(0)
        err = eo.read().decode().strip()
    return {"rc": p.returncode, "seconds": seconds, "peak_mb": usage.ru_maxrss / 1024,
            "stderr_lines": len(err.splitlines()), "stderr": err[:200]}


def _interrupt(tmp: Path, sig: int) -> dict:
    out = tmp / f"rot_{sig}"
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    p = subprocess.Popen([*PCREG, "evaluate", "rotation", "--data", "synthetic:syn1a", "--frames", "3", "--size",
                          "320x240", "--angles", "0:180:5", "--samples", "3", "--workers", "2", "--out", str(out)],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, start_new_session=True)
    while not list(out.glob("units/**/*.json")) and p.poll() is None:
        time.sleep(0.05)
    children = subprocess.run(["pgrep", "-P", str(p.pid)], capture_output=True, text=True).stdout.split()
    t0 = time.perf_counter()
    if sig == signal.SIGINT:
        os.killpg(p.pid, sig)
    else:
        p.send_signal(sig)
    p.communicate(timeout=120)
    stop = time.perf_counter() - t0
    time.sleep(0.5)
    left = [c for c in children if Path(f"/proc/{c}").exists()]
    return {"rc": p.returncode, "stop_seconds": stop, "workers": len(children), "workers_left": len(left),
            "units_kept": len(list(out.glob("units/**/*.json")))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        t = Path(d)
        (t / "big30k.png").write_bytes(_png(30000, 30000))
        (t / "big100k.png").write_bytes(_png(100000, 100000))
        os.mkfifo(t / "fifo.png")
        good = t / "good.png"
        import cv2

        cv2.imwrite(str(good), np.random.default_rng(0).integers(0, 256, (120, 160, 3), dtype=np.uint8))
        scan = SHARED_DATA / "scans" / "source.ply"
        if scan.is_file():
            data = scan.read_bytes()
        else:
            pts = np.random.default_rng(1).normal(size=(70000, 3)).astype("<f4")
            data = (b"ply\nformat binary_little_endian 1.0\nelement vertex 70000\nproperty float x\n"
                    b"property float y\nproperty float z\nend_header\n" + pts.tobytes())
        (t / "whole.ply").write_bytes(data)
        (t / "truncated.ply").write_bytes(data[:20000])
        cases = {
            "missing file (baseline)": ["register", str(t / "missing.png"), str(good)],
            "PNG declaring 30000x30000": ["register", str(t / "big30k.png"), str(good)],
            "PNG declaring 100000x100000": ["register", str(t / "big100k.png"), str(good)],
            "FIFO as an image": ["register", str(t / "fifo.png"), str(good)],
            "/dev/zero as an image": ["register", "/dev/zero", str(good)],
            "truncated binary PLY (20 kB of 1.1 MB)": ["crosscheck", str(t / "truncated.ply"), str(t / "whole.ply"),
                                                       "--json"],
            "--angles 0:360:1e-9": ["evaluate", "rotation", "--angles", "0:360:1e-9", "--out", str(t / "r")],
            "--fusion-weight inf": ["evaluate", "sequence", "--fusion-weight", "inf", "--out", str(t / "s")],
        }
        rows = {}
        for name, argv in cases.items():
            runs = [_run_rss(argv) for _ in range(args.repeats)]
            rows[name] = {"rc": runs[0]["rc"], "stderr_lines": runs[0]["stderr_lines"], "stderr": runs[0]["stderr"],
                          "seconds": float(np.median([r["seconds"] for r in runs])),
                          "peak_mb": float(np.median([r["peak_mb"] for r in runs]))}
        interrupts = {"SIGINT (Ctrl-C)": _interrupt(t, signal.SIGINT), "SIGTERM": _interrupt(t, signal.SIGTERM)}
    base = rows["missing file (baseline)"]
    lines = ["### Hostile input through the command line\n",
             "| input | exit | stderr lines | seconds (median) | extra s vs baseline | peak MB | extra MB |",
             "|---|---|---|---|---|---|---|"]
    for name, r in rows.items():
        lines.append(f"| {name} | {r['rc']} | {r['stderr_lines']} | {r['seconds']:.2f} | "
                     f"{r['seconds'] - base['seconds']:+.2f} | {r['peak_mb']:.0f} | {r['peak_mb'] - base['peak_mb']:+.0f} |")
    lines += ["", "### Interrupting `evaluate rotation --workers 2`\n",
              "| signal | exit | seconds to stop | worker processes | left behind | finished units kept |",
              "|---|---|---|---|---|---|"]
    for name, r in interrupts.items():
        lines.append(f"| {name} | {r['rc']} | {r['stop_seconds']:.2f} | {r['workers']} | {r['workers_left']} | "
                     f"{r['units_kept']} |")
    checks = [(f"{n}: exit 2, one line, < 2 s and < 200 MB over the baseline",
               f"exit {r['rc']}, {r['stderr_lines']} line(s), {r['seconds'] - base['seconds']:+.2f} s, "
               f"{r['peak_mb'] - base['peak_mb']:+.0f} MB", r["rc"] == 2 and
               r["stderr_lines"] == 1 and r["seconds"] - base["seconds"] < 2 and r["peak_mb"] - base["peak_mb"] < 200)
              for n, r in rows.items()]
    checks += [(f"{n}: exit 130 within 5 s, no worker left, units kept",
                f"exit {r['rc']}, {r['stop_seconds']:.2f} s, {r['workers_left']} left, {r['units_kept']} kept",
                r["rc"] == 130 and
                r["stop_seconds"] < 5 and r["workers_left"] == 0 and r["units_kept"] > 0)
               for n, r in interrupts.items()]
    md = "\n".join(lines) + "\n\n" + checks_markdown(checks)
    write_report(args.out, "bench_hostile", {"cases": rows, "interrupts": interrupts, "machine": machine_info()}, md)
    print(md)


if __name__ == "__main__":
    main()
