"""The demo's report (report.md) and its figure of one pair, from the results of its parts."""

from __future__ import annotations

from pathlib import Path

def pair_figure(frames, *, k: int, weight: float, out: Path, title: str) -> None:
    """Reference, moving, warped, truth and the predictions of one pair (a figure to look at); the
    pixels that are not scored (unknown truth) are grey in the predictions too."""
    from ...outputs import pyplot

    plt = pyplot()
    import numpy as np

    from ...outputs import atomic_save_figure
    from ...classification.bayes import fit_classifier
    from ...pipeline import PipelineConfig, TemporalFusion, process_pair
    from ...recording.entities import CLASSES

    i = 0
    j = min(i + k, len(frames) - 1)
    clf = fit_classifier([frames[i]], features=PipelineConfig().features)
    done = process_pair(frames[i], frames[j], clf, weight=weight, indices=(i, j), keep_arrays=True,
                        temporal=TemporalFusion(frames[i].labels, weight=weight))
    res, ex = done.result, done.arrays
    unknown = frames[j].labels == 2

    def shown(pred):
        return colours[np.where(unknown, 2, pred)]

    colours = np.array([CLASSES[c][1] for c in sorted(CLASSES)], dtype=np.uint8)
    panels = [
        (frames[i].image, f"reference frame {i}"),
        (frames[j].image, f"moving frame {j}"),
        (np.where(ex.valid[..., None], ex.warped, 0), "moving warped onto the reference"),
        (colours[frames[j].labels], f"truth of frame {j}"),
        (shown(ex.predicted["plain"]), f"naive Bayes: {res.errors['plain']:.1f}% error"),
        (shown(ex.predicted["augmented"]), f"augmented (w = {weight:g}): {res.errors['augmented']:.1f}% error"),
    ]
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.4))
    for ax, (img, label) in zip(axes.flat, panels):
        ax.imshow(img)
        ax.set_title(label, fontsize=10)
        ax.axis("off")
    fig.suptitle(f"{title}: frame {j} registered to frame {i}; green ground, red obstacle, grey unknown (not scored)",
                 fontsize=11)
    fig.tight_layout()
    atomic_save_figure(fig, out)
    plt.close(fig)


_METHODS_TEXT = """Frame i + k is registered to frame i; naive Bayes is trained on frame i. Error rates in percent,
unknown truth left out; the fusion weight w is chosen on the first frames of each sequence, which are
not scored.

- `plain`: naive Bayes on frame i + k, against its labels.
- `thesis_before` / `thesis_after`: naive Bayes on frame i + k unregistered / warped onto frame i
  (black border included), against frame i's labels (the thesis's before and after).
- `thesis_after_masked` / `thesis_after_cropped`: the border classified from the unwarped frame / left out.
- `augmented`: naive Bayes fused with frame i's labels warped into frame i + k as a prior.
- `augmented_unregistered`: the same prior without the warp (what registration adds).
- `augmented_temporal`: labels used only at the start of each chain, then carried frame to frame.
- `propagated`: frame i's warped labels alone (naive Bayes where they say nothing).
- `augmented_flow`: the same fusion, the prior warped by OpenCV's DIS optical flow (a baseline).
"""


def report(config, cres, rres, sres, cc, stage_rows, times, record, out: Path, stres: dict | None = None) -> str:
    from ...outputs import markdown_table
    from . import classification, rotation, sequence
    from . import stream as stream_report

    parts = ["# pcreg demo\n",
             f"Synthetic presets {', '.join(config.presets)} ({config.frames} frames of "
             f"{config.size[0]}x{config.size[1]}, seed {config.seed}). Every number below was computed by this run; "
             "the full-size evaluations are `pcreg evaluate classification|rotation|sequence`.\n"]
    parts.append("## 1. Naive Bayes alone (thesis Ch. 4)\n")
    for name, (header, rows) in classification.tables(cres).items():
        if name in ("case1", "case2"):
            parts.append(f"**{name}**\n\n" + markdown_table(header, rows))
    parts.append("![Case I](classification/case1.png)\n")
    parts.append("## 2. Rotated frames before and after registration (thesis Ch. 5)\n")
    header, rows = rotation.table(rres, "reference")
    parts.append("Backend reference:\n\n" + markdown_table(header, rows))
    header, rows = rotation.table(rres, "open3d")
    parts.append("\nBackend open3d:\n\n" + markdown_table(header, rows))
    parts.append("\n" + rotation.checks(rres))
    parts.append("![rotation](rotation/rotation.png)\n")
    parts.append("## 3. The two ICP backends on the same clouds\n")
    rows = [[b, cc[b]["fitness"], cc[b]["inlier_rmse"], cc[b]["iterations"], 1000.0 * cc[b]["seconds"]]
            for b in ("reference", "open3d")]
    parts.append(markdown_table(["backend", "fitness", "inlier RMSE px", "iterations", "ms"], rows, digits=4))
    parts.append(f"\nLargest corner disagreement {cc['max_corner_disagreement_px']:.4f} px, rotation "
                 f"{cc['rotation_disagreement_deg']:.4f} degrees (full report: crosscheck.json).\n")
    parts.append("## 4. Sequences: registration and label propagation (thesis Ch. 6-7)\n")
    parts.append("![pair](pair.png)\n")
    parts.append(_METHODS_TEXT)
    for b in sres["backends"]:
        header, rows = sequence.table(sres, b)
        parts.append(f"Backend {b}, mean error % over pairs (i, i+k):\n\n" + markdown_table(header, rows) + "\n")
    parts.append(sequence.checks(sres))
    for name in sres["datasets"]:
        parts.append(f"![{name}](sequence/sequence_{name}.png)\n")
    parts.append("![summary](sequence/sequence_summary.png)\n")
    if stres is not None:
        parts.append("## 5. A stream labelled from its key frame (`pcreg run`, `pcreg evaluate stream`)\n")
        parts.append("Each preset as a stream: its first frame is the key frame with its labels; every later frame "
                     "is labelled by naive Bayes alone (`plain`), with the key frame's labels unwarped "
                     "(`unregistered`), by pcreg (the key frame's labels carried by a dense field and by DIS flow, "
                     "each trusted per pixel by how well the key frame carried along it matches the frame, each label "
                     "read from the evidence of its neighbourhood (the fused log-odds blurred by a few pixels), and "
                     "naive Bayes learning from the frames it labels surely) and with DIS optical flow from the key "
                     "frame alone (`flow_key`, at the same weight everywhere, each pixel read alone). Mean error % per "
                     "clip:\n")
        header, rows, footer = stream_report.table(stres)
        parts.append(markdown_table(header, rows) + footer)
        parts.append(stream_report.checks(stres))
        parts.append("![stream](stream/stream.png)\n")
    parts.append("## 6. Pipeline stage times (median ms per pair in this run, this machine)\n")
    parts.append(markdown_table(["backend", "pairs", "register", "warp", "classify", "fuse", "total"], stage_rows, digits=1))
    parts.append("\n`tools/bench_pipeline.py` measures 640x480 frames.\n")
    parts.append("## Run\n")
    parts.append(markdown_table(["part", "seconds"], [[k, v] for k, v in times.items()], digits=1))
    if record is not None:
        parts.append(f"\nRecording: `{record}` (`pcreg view {record}`).\n")
    return "\n".join(parts)
