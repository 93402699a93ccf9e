"""A process that reads videos for the video fuzz suite (tests/test_fuzz_videos.py), one a request, so that a crash of
FFmpeg's ends this process, not the tests'. Each line on stdin is a video's path; each line on stdout the answer, JSON:
``{"read": FRAMES}`` (every frame read, all of one size), ``{"refused": MESSAGE}`` (a PcregError, as the command line
prints it), ``{"error": TRACEBACK}`` (any other exception, or a result that is not frames) or ``{"hang": SECONDS}``."""

from __future__ import annotations

import json
import signal
import sys
import traceback

HANG_SECONDS = 20


class Hang(BaseException):
    pass


def _alarm(signum, frame):
    raise Hang


def read_all(path: str) -> int:
    """Open the video at ``path`` as a run does and read every frame; how many."""
    import numpy as np

    from pcreg.datasets.sources import open_frames

    frames = open_frames(path)
    shape, n = None, 0
    for frame in frames.frames():
        image = frame.image
        assert isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
        assert shape is None or image.shape == shape, (image.shape, shape)
        shape, n = image.shape, n + 1
    assert n > 0
    return n


def answer(path: str) -> dict:
    from pcreg.cli import _one_line
    from pcreg.errors import PcregError

    signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(HANG_SECONDS)
    try:
        return {"read": read_all(path)}
    except PcregError as exc:
        return {"refused": _one_line(exc)}
    except Hang:
        return {"hang": HANG_SECONDS}
    except Exception:  # noqa: BLE001 - what the suite reports as a failure
        return {"error": traceback.format_exc()}
    finally:
        signal.alarm(0)


def main() -> None:
    out = sys.stdout
    sys.stdout = sys.stderr  # the answers alone on stdout
    import pcreg.datasets.sources  # noqa: F401 - loaded before the first request, as the parent waits on it

    out.write("ready\n")
    out.flush()
    for line in sys.stdin:
        out.write(json.dumps(answer(line.rstrip("\n"))) + "\n")
        out.flush()


if __name__ == "__main__":
    main()
