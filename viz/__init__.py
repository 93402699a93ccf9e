"""Offline viewing of pcreg's rerun recordings: entity paths and the blueprint embedded in every recording.

``viz.entities`` has no dependencies; ``viz.blueprint`` imports ``rerun.blueprint``.
"""

from __future__ import annotations

__all__ = ["blueprint", "entities"]
