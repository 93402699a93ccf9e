"""Text inputs saved as UTF-16 or UTF-32 (Notepad's "Unicode", PowerShell's default) are named as such: a text
matrix (``--init``, a truth), a .xyz/.xyzn/.pts cloud and a class table were refused quoting bytes ("could not
convert string 'ÿþ1\\x00' to float64", "its first point line ('��2\\x00.\\x007...')"); a .csv/.txt cloud already was."""

import numpy as np
import pytest

from pcreg.classes.files import read_table_file
from pcreg.cloud_reader import load_cloud
from pcreg.errors import InputError
from pcreg.text_files import read_text_matrix

ENCODINGS = [("utf-16", "UTF-16"), ("utf-16-le", "UTF-16"), ("utf-16-be", "UTF-16"), ("utf-32", "UTF-32"),
             ("utf-32-le", "UTF-32"), ("utf-32-be", "UTF-32")]
BOM_32_BE = b"\0\0\xfe\xff"
LABELMAP = "# label:color_rgb:parts:actions\nbackground:0,0,0::\nroad:128,64,128::\ncar:64,0,128::\n"


@pytest.mark.parametrize("encoding, said", ENCODINGS)
def test_a_text_matrix(tmp_path, encoding, said):
    path = tmp_path / "init.txt"
    path.write_bytes("1 0 0\n0 1 0\n0 0 1\n".encode(encoding))
    with pytest.raises(InputError, match=rf"^{path}: it is {said} text \(as some Windows programs save it\); save it "
                                         "as UTF-8 or ASCII$"):
        read_text_matrix(path)
    path.write_bytes("\ufeff1 0 0\n0 1 0\n0 0 1\n".encode())  # UTF-8 with its mark: read
    assert np.array_equal(read_text_matrix(path), np.eye(3))


@pytest.mark.parametrize("encoding, said", ENCODINGS)
@pytest.mark.parametrize("suffix", [".xyz", ".pts"])
def test_a_text_cloud_open3d_reads(tmp_path, encoding, said, suffix):
    rows = "".join(f"{x}.5 {x % 3} {x % 5}\n" for x in range(20))
    path = tmp_path / f"c{suffix}"
    path.write_bytes((("20\n" if suffix == ".pts" else "") + rows).encode(encoding))
    with pytest.raises(InputError, match=rf"^{path}: it is {said} text"):
        load_cloud(path)
    path.write_bytes((("20\n" if suffix == ".pts" else "") + rows).encode())
    assert load_cloud(path).shape == (20, 3)


@pytest.mark.parametrize("encoding, said", ENCODINGS)
@pytest.mark.parametrize("name", ["labelmap.txt", "table.json"])
def test_a_class_table(tmp_path, encoding, said, name):
    text = LABELMAP if name.endswith(".txt") else \
        '{"classes": [{"name": "road", "colour": [128, 64, 128]}, {"name": "car", "colour": [64, 0, 128]}]}'
    path = tmp_path / name
    path.write_bytes(text.encode(encoding))
    with pytest.raises(InputError, match=rf"^{path}: it is {said} text"):
        read_table_file(path)


def test_a_zip_or_an_image_given_as_a_class_table_is_still_named_as_one(tmp_path):
    import zipfile

    import cv2

    with zipfile.ZipFile(tmp_path / "export.zip", "w") as z:
        z.writestr("labelmap.txt", LABELMAP)
    cv2.imwrite(str(tmp_path / "mask.png"), np.zeros((8, 8), np.uint8))
    with pytest.raises(InputError, match="it is a zip archive"):
        read_table_file(tmp_path / "export.zip")
    with pytest.raises(InputError, match="it is an image, not a class table"):
        read_table_file(tmp_path / "mask.png")


def test_utf32_with_a_big_endian_mark(tmp_path):
    path = tmp_path / "init.txt"
    path.write_bytes(BOM_32_BE + "1 0 0\n0 1 0\n0 0 1\n".encode("utf-32-be"))
    with pytest.raises(InputError, match=rf"^{path}: it is UTF-32 text"):
        read_text_matrix(path)


@pytest.mark.parametrize("name", ["c.xyz", "init.txt", "labelmap.txt", "table.json"])
def test_a_file_of_zero_bytes_is_not_called_utf16(tmp_path, name):
    """What a crash or a lost power can leave: not text of any kind, each reader's own message as before."""
    path = tmp_path / name
    path.write_bytes(b"\0" * 4096)
    read = {".xyz": load_cloud, ".txt": read_text_matrix, ".json": read_table_file}[path.suffix]
    read = read_table_file if name == "labelmap.txt" else read
    with pytest.raises(InputError) as caught:
        read(path)
    assert "UTF-16" not in str(caught.value) and "UTF-32" not in str(caught.value)
