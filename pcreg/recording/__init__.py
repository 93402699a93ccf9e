"""Offline viewing of pcreg's rerun recordings: entity paths and the blueprint embedded in every recording.

``pcreg.recording.entities`` has no dependencies; ``pcreg.recording.blueprint`` imports ``rerun.blueprint``.
"""

from __future__ import annotations

__all__ = ["blueprint", "entities"]
