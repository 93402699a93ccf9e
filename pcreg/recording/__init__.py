"""Recordings of pcreg's runs and how they are viewed: entity paths, the recorder, one blueprint per kind
of recording, reading recordings back, staging them (one, or several side by side) for a viewer, the
viewer's processes (native, headless, web) and the report page's server.

``pcreg.recording.entities`` and ``pcreg.recording.null`` (the recorder that records nothing) have no
dependencies; the other modules import rerun.
"""

from __future__ import annotations

__all__ = ["blueprint", "entities", "null", "readback", "recorder", "report", "staging", "viewer"]
