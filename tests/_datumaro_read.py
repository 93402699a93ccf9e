"""Run by a Python that has Datumaro (``.venv-datumaro``, which ``make test`` sets up: Datumaro pins opencv<5 and
pillow 12, below pcreg's): ``python _datumaro_read.py FOLDER OUT.npz`` reads FOLDER with Datumaro's
``voc_segmentation`` importer (the reader CVAT's "Segmentation mask 1.1" import calls) and writes what it found:
``names`` (the label categories in order), ``items`` (the item ids) and, for each item and each label, the
union of that label's masks as ``mask/ITEM/LABEL`` (absent where the item has none)."""

import sys

import numpy as np
from datumaro.components.annotation import AnnotationType
from datumaro.components.dataset import Dataset


def main(folder: str, out: str) -> None:
    dataset = Dataset.import_from(folder, "voc_segmentation")
    names = [c.name for c in dataset.categories()[AnnotationType.label]]
    found = {"names": np.array(names), "items": np.array(sorted(item.id for item in dataset))}
    for item in dataset:
        for a in item.annotations:
            if a.type == AnnotationType.mask:
                key = f"mask/{item.id}/{names[a.label]}"
                found[key] = found[key] | a.image.astype(bool) if key in found else a.image.astype(bool)
    np.savez(out, **found)


if __name__ == "__main__":
    main(*sys.argv[1:3])
