"""pcreg.quiet.capture_output_fds: what C code prints is kept off the terminal, and captures on two threads
at once (pcreg run decodes on its reader thread while its writer reads a truth map) leave the process's
file descriptors 1 and 2, and the main thread's sys.stdout, as they were."""

from __future__ import annotations

import os
import sys
import threading

from pcreg.quiet import capture_output_fds


def _same_file(fd: int, stat) -> bool:
    now = os.fstat(fd)
    return (now.st_dev, now.st_ino) == (stat.st_dev, stat.st_ino)


def test_captures_on_two_threads_at_once_leave_the_descriptors_and_stdout_as_they_were(capfd):
    before = [os.fstat(1), os.fstat(2)]
    stdout = sys.stdout
    heard: list[str] = []
    stop = threading.Event()

    def other() -> None:
        while not stop.is_set():
            with capture_output_fds() as said:
                os.write(2, b"from the other thread\n")
            heard.append("".join(said))

    thread = threading.Thread(target=other)
    thread.start()
    try:
        # at least 200 captures here, and on until the other thread has made 200 meanwhile: a fixed count
        # here could end before a loaded machine had given the other thread its first turn
        captures = 0
        while (captures < 200 or len(heard) < 200) and thread.is_alive():
            with capture_output_fds() as said:
                os.write(1, b"from the main thread\n")
            assert "".join(said) == "from the main thread\n"
            captures += 1
    finally:
        stop.set()
        thread.join()
    assert len(heard) >= 200 and all(h == "from the other thread\n" for h in heard)
    assert _same_file(1, before[0]) and _same_file(2, before[1]) and sys.stdout is stdout
    os.write(1, b"after\n")
    assert capfd.readouterr().out == "after\n"  # nothing captured leaked, the terminal is the terminal again
