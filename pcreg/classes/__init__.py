"""Classes as data: a class table (each class's id, name and colour, and which id is unknown), the
built-in tables, a table from CVAT's ``labelmap.txt`` or a small JSON, and label PNGs read and written
through a table.

- :mod:`pcreg.classes.table`: :class:`ClassTable`, the built-ins ``lagr``, ``camvid11``, ``davis``;
- :mod:`pcreg.classes.files`: ``labelmap.txt`` and JSON, and :func:`class_table` (what ``--classes`` names);
- :mod:`pcreg.classes.png`: :func:`write_label_png` and :func:`read_label_png`, the one pair.
"""

from __future__ import annotations

from .files import (LABELMAP_FILE, class_table, labelmap_text, parse_labelmap, parse_table_json, read_labelmap,
                    read_table_file, table_json, voc_colormap, write_labelmap)
from .png import decode_label_png, encode_label_png, is_palette_png, read_label_png, write_label_png
from .table import CAMVID11, DAVIS, DEFAULT_TABLE, LAGR, TABLES, ClassTable, LabelClass, check_tables_agree

__all__ = ["ClassTable", "LabelClass", "LAGR", "CAMVID11", "DAVIS", "TABLES", "DEFAULT_TABLE", "check_tables_agree",
           "LABELMAP_FILE", "class_table", "labelmap_text", "parse_labelmap", "parse_table_json", "read_labelmap",
           "read_table_file", "table_json", "voc_colormap", "write_labelmap",
           "encode_label_png", "write_label_png", "decode_label_png", "read_label_png", "is_palette_png"]
