"""The memory a run is expected to need, and the note before it starts when the machine has less."""

import pytest

import numpy as np

from pcreg.classes import CAMVID11, ClassTable, LabelClass
from pcreg.runs.memory import available_bytes, memory_note, run_bytes, run_note

GIB = 2**30


def test_the_expected_memory_grows_with_the_classes_and_falls_with_the_scale():
    two, eleven = run_bytes(1280, 720, 2), run_bytes(1280, 720, 11)
    assert two < eleven
    assert run_bytes(1280, 720, 11, 0.5) < eleven
    # what pcreg run reached over eight 1280x720 frames (603 MB, 1031 MB, and 620 MB at --scale 0.5): each
    # expectation above it, by no more than a fifth
    for expected, measured in ((two, 603), (eleven, 1031), (run_bytes(1280, 720, 11, 0.5), 620)):
        assert measured * 2**20 <= expected <= 1.2 * measured * 2**20
    assert run_bytes(3840, 2160, 11) > 5.5 * GIB  # 4K frames, eleven classes


def test_no_note_when_the_run_fits_or_the_system_does_not_say():
    assert memory_note(640, 480, 11, 1.0, 8 * GIB) is None
    assert memory_note(3840, 2160, 11, 1.0, None) is None


def test_the_note_names_the_largest_scale_that_fits():
    need = run_bytes(3840, 2160, 11)
    note = memory_note(3840, 2160, 11, 1.0, run_bytes(3840, 2160, 11, 0.5) + 1)
    assert note is not None and f"about {need / GIB:.1f} GiB" in note and "3840x2160 frames with 11 classes" in note
    assert note.endswith(f"--scale 0.5 needs about {run_bytes(3840, 2160, 11, 0.5) / GIB:.1f} GiB")
    assert "--scale 0.75" not in note
    tight = memory_note(3840, 2160, 11, 0.5, 100 * 2**20)
    assert tight is not None and "at --scale 0.5" in tight and tight.endswith("free memory or give smaller frames")


@pytest.mark.parametrize("text, expected", [
    ("MemTotal:       16000000 kB\nMemAvailable:    2048 kB\n", 2048 * 1024),
    ("MemTotal:       16000000 kB\n", None),  # an old kernel: no MemAvailable
    ("MemAvailable: lots\n", None),
])
def test_the_available_memory_is_read_from_meminfo(tmp_path, text, expected):
    path = tmp_path / "meminfo"
    path.write_text(text)
    assert available_bytes(path, cgroups=()) == expected
    assert available_bytes(tmp_path / "absent", cgroups=()) is None


@pytest.mark.parametrize("version", ["v2", "v1"])
def test_a_containers_memory_limit_is_what_is_available_where_it_is_less(tmp_path, version):
    """Inside a container (``docker run --memory 2g``) MemAvailable is the host's: a run the limit cannot hold was
    killed by the system with no note before it. The limit less the use (the page cache the kernel reclaims first
    not counted) is what is available where it is less; no limit, or none readable, leaves MemAvailable."""
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemAvailable:   64000000 kB\n")  # the host's 61 GiB
    limit, use, stat = (tmp_path / n for n in ("limit", "use", "stat"))
    inactive = "inactive_file" if version == "v2" else "total_inactive_file"
    files = ((str(limit), str(use), str(stat), inactive),)
    limit.write_text(f"{2 * GIB}\n")
    use.write_text(f"{GIB // 2}\n")
    stat.write_text(f"anon 100\n{inactive} {GIB // 4}\nactive_file 5\n")
    assert available_bytes(meminfo, files) == 2 * GIB - GIB // 4  # 512 MiB used, 256 MiB of it cache
    note = run_note([np.zeros((2160, 3840), np.uint8)], CAMVID11, 1.0, available_bytes(meminfo, files))
    assert note is not None and "1.8 GiB is available" in note
    stat.unlink()  # no statistics: the use as it is
    assert available_bytes(meminfo, files) == 2 * GIB - GIB // 2
    use.write_text(f"{3 * GIB}\n")  # over the limit already: nothing left
    assert available_bytes(meminfo, files) == 0
    for none in ("max\n", "9223372036854771712\n", "lots\n"):  # v2's and v1's no limit, and garbage
        limit.write_text(none)
        assert available_bytes(meminfo, files) == 64000000 * 1024
    limit.unlink()
    assert available_bytes(meminfo, files) == 64000000 * 1024


def test_a_large_table_counts_the_classes_its_key_frames_show():
    """A table of 254 classes whose key frames show thirteen needs what thirteen classes need (the step's maps are
    the learned classes'): no note where eleven fit; a note when they show every class."""
    table = ClassTable(tuple(LabelClass(i, f"c{i}", (i + 1, 0, 0)) for i in range(254))
                       + (LabelClass(254, "void", (0, 0, 0)),), 254, "t.json")
    keys = [np.full((720, 1280), 254, np.uint8), np.zeros((720, 1280), np.uint8)]
    keys[0][:11] = np.arange(240, 251, dtype=np.uint8)[:, None]
    keys[1][:, :3] = 7
    available = run_bytes(1280, 720, 13) + 1
    assert run_note(keys, table, 1.0, available) is None  # thirteen: 240..250, 0 and 7
    keys[1][:1, :254] = np.arange(254, dtype=np.uint8)
    note = run_note(keys, table, 1.0, available)
    assert note is not None and "1280x720 frames with 254 classes" in note
