"""The weather vocabulary every part of wcbench shares (docs/design.md §4).

``clear`` is the raw, unedited scene; ``rain``, ``snow`` and ``fog`` are the edits. Methods
declare the subset they support; the reference model's physics, the image-space baseline, the
metrics' applicability rules and the CLI all draw their names from here.
"""

from __future__ import annotations

#: Every weather wcbench knows, in display order; ``clear`` means the raw, unedited scene.
WEATHERS: tuple[str, ...] = ("clear", "rain", "snow", "fog")
#: The weathers that are edits of the raw scene.
EDITED_WEATHERS: tuple[str, ...] = WEATHERS[1:]
