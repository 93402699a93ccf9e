"""Recordings of pcreg's runs and how they are viewed: entity paths, the recorder, one blueprint per kind
of recording, reading recordings back, staging them (one, or several side by side) for a viewer, the
viewer's processes (native, headless, web) and the report page's server.

The recorder's interface is ``pcreg.recording.interface.RecorderProtocol``; ``pcreg.recording.recorder``
implements it over the file (``sink``) and one logger a kind of log (``text_log``, ``pair_log``,
``icp_log``, ``dense_log``, ``evaluation_log``, ``crosscheck_log``), ``pcreg.recording.null`` by recording
nothing. ``entities``, ``interface`` and ``null`` have no dependencies; ``values`` needs numpy; the other
modules import rerun (the only ones in pcreg that do).
"""

from __future__ import annotations

__all__ = ["blueprint", "crosscheck_log", "dense_log", "entities", "evaluation_log", "icp_log", "interface", "null",
           "pair_log", "readback", "recorder", "report", "sink", "staging", "text_log", "values", "viewer"]
