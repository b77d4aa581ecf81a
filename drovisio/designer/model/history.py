"""Undo and redo: snapshots of a design's editable state, on two bounded stacks."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drovisio.designer.model.marker import DesignMarker

__all__ = ["UNDO_LIMIT", "Snapshot", "UndoHistory"]

#: Edits kept for undo (the oldest are dropped).
UNDO_LIMIT = 200


@dataclass
class Snapshot:
    """What undo restores: the edited fields of a design (not the mesh, nor the defaults for
    the next marker). ``brick_from_mesh`` is 4x4, metres."""

    units: str
    brick_from_mesh: np.ndarray
    markers: tuple[DesignMarker, ...]
    first_id: int | None
    ids_per_instance: int | None
    instances: int
    symmetry: str
    code_family: str
    name: str
    description: str | None
    selected: int | None


@dataclass
class UndoHistory:
    """The undo and redo stacks of one design."""

    undo_stack: list[Snapshot] = field(default_factory=list)
    redo_stack: list[Snapshot] = field(default_factory=list)

    @property
    def can_undo(self) -> bool:
        return bool(self.undo_stack)

    @property
    def can_redo(self) -> bool:
        return bool(self.redo_stack)

    def record(self, before: Snapshot) -> None:
        """Keep the state before an edit; a new edit forgets what was undone."""
        self.undo_stack.append(before)
        del self.undo_stack[:-UNDO_LIMIT]
        self.redo_stack.clear()

    def undo(self, current: Snapshot) -> Snapshot | None:
        """The state to go back to (None: nothing to undo); ``current`` becomes redoable."""
        if not self.undo_stack:
            return None
        self.redo_stack.append(current)
        return self.undo_stack.pop()

    def redo(self, current: Snapshot) -> Snapshot | None:
        """The state to go forward to (None: nothing to redo); ``current`` becomes undoable."""
        if not self.redo_stack:
            return None
        self.undo_stack.append(current)
        return self.redo_stack.pop()

    def copy(self) -> UndoHistory:
        """Independent stacks holding the same (immutable once taken) snapshots."""
        return UndoHistory(list(self.undo_stack), list(self.redo_stack))
