"""What an evaluation returns: :class:`Results`, typed at the top, its tables as results.json holds them.

Every evaluation (:mod:`.classification`, :mod:`.rotation`, :mod:`.sequence`, :mod:`.stream`) returns one.
:meth:`Results.to_dict` is the results.json document; the reports (:mod:`.reports`) read that document and
nothing else, the same one that ``pcreg view OUT_DIR`` reads back from disk.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

KINDS = ("classification", "rotation", "sequence", "stream")
#: The top-level sections one kind of evaluation has and the others do not (:attr:`Results.sections`).
SECTIONS = ("k", "weight_search", "average_reduction", "calibration", "davis")


@dataclass(frozen=True)
class Results:
    """One evaluation's numbers.

    kind : ``"classification"``, ``"rotation"``, ``"sequence"`` or ``"stream"``.
    config : the evaluation's configuration as plain JSON values (config.json).
    datasets : per dataset (a sequence or clip), the first backend's tables: for a sequence, the mean
        error of each method per increment; for a clip, each method's mean error and its reduction against
        plain; for rotation, each angle's errors; for classification, the dataset's frames and classes.
    units : every unit's own result, in plan order, as ``OUT/units/*.json`` keeps it (resume reads them).
    resumed_units : units read back from an earlier run instead of run again.
    seconds : wall time of the whole evaluation.
    primary_backend : the backend of ``datasets`` (None for classification, which registers nothing).
    methods : the methods compared, in table order (sequence, stream).
    backends : per backend, its own ``datasets`` tables (rotation, sequence).
    notes : what the tables' readers should know (a scaled k, a refused pair).
    data_notes : what reading the data met, as said on stderr when it was read (a frame that decodes around damaged
        data, transparent pixels, 16-bit values read as nearly black, a grey frame among colour ones, a frame missing
        from a DAVIS sequence's numbering; :func:`pcreg.datasets.frame.damage_notes`): the figures of those frames
        may be off.
    sections : the sections of one kind of evaluation (:data:`SECTIONS`), each also read as an attribute
        (None where absent):

        - ``k`` (classification): the training sizes of cases I and III per dataset;
        - ``weight_search`` (classification): the thesis feature weights found per dataset;
        - ``average_reduction`` (stream): each method's mean over clips of its reduction of plain's error (%);
        - ``calibration`` (stream): pcreg's confidence (pcreg_object's when pcreg did not run; with neither, a
          section of no pixels) over every clip's known pixels
          (:func:`pcreg.experiments.stream.calibration`);
        - ``davis`` (stream on DAVIS): J and F per sequence and method, beside the published methods
          (:func:`pcreg.experiments.stream_davis.summarise_davis`).
    """

    kind: str
    config: dict
    datasets: dict[str, dict]
    units: list[dict]
    resumed_units: int = 0
    seconds: float = 0.0
    primary_backend: str | None = None
    methods: tuple[str, ...] | None = None
    backends: dict[str, dict] | None = None
    notes: tuple[str, ...] | None = None
    data_notes: tuple[str, ...] | None = None
    sections: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {self.kind!r}")
        unknown = sorted(set(self.sections) - set(SECTIONS))
        if unknown:
            raise ValueError(f"unknown results section(s) {', '.join(unknown)}; the sections are {', '.join(SECTIONS)}")

    @property
    def k(self) -> dict | None:
        """Classification: the training sizes of cases I and III per dataset."""
        return self.sections.get("k")

    @property
    def weight_search(self) -> list[dict] | None:
        """Classification: the thesis feature weights found per dataset."""
        return self.sections.get("weight_search")

    @property
    def average_reduction(self) -> dict[str, float] | None:
        """Stream: each method's mean over clips of its reduction of plain's error (%)."""
        return self.sections.get("average_reduction")

    @property
    def calibration(self) -> dict | None:
        """Stream: pcreg's confidence over every clip's known pixels."""
        return self.sections.get("calibration")

    @property
    def davis(self) -> dict | None:
        """Stream on DAVIS: J and F per sequence and method, beside the published methods."""
        return self.sections.get("davis")

    def to_dict(self) -> dict[str, Any]:
        """The results.json document: the fields in this order, those an evaluation does not have left out."""
        doc: dict[str, Any] = {"config": self.config}
        optional = {"primary_backend": self.primary_backend,
                    "methods": None if self.methods is None else list(self.methods)}
        doc.update((k, v) for k, v in optional.items() if v is not None)
        doc["datasets"] = self.datasets
        later = {"backends": self.backends, "k": self.k, "notes": None if self.notes is None else list(self.notes),
                 "data_notes": list(self.data_notes) if self.data_notes else None,
                 "weight_search": self.weight_search, "average_reduction": self.average_reduction,
                 "calibration": self.calibration, "davis": self.davis}
        doc.update((k, v) for k, v in later.items() if v is not None)
        doc.update(units=self.units, resumed_units=self.resumed_units, seconds=self.seconds)
        return doc
