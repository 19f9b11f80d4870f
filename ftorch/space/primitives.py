"""The kinds of primitive (3.4), defined once: the codes of salient points in
``ImageRecords.kind``, the layout of their descriptors, and :class:`PartKind`, the kind of a
feature's part, which knows its salient points, its descriptor slots and its size."""
from __future__ import annotations

from enum import StrEnum

from torch import Tensor

from .texture import BINS

EDGEL, BLOB, CORNER = 0, 1, 2  # salient point codes (-1: padding)
DESCRIPTOR = 15  # [basis @ level-1 | basis @ level | basis @ level+1] (3.4.2)
EDGEL_SLOTS = slice(5, 7)  # an edgel's first-order pair at its own level (3.4.1)


class PartKind(StrEnum):
    """A part is a texel (a salient blob or corner: 15 numbers, 3.4.2), an edgel (2 numbers,
    3.4.1) or a texture (the square-rooted histogram, ``BINS`` numbers, 7.2.1, sampled from the
    texture grid: no salient points, no descriptor slots, no orientation). Its value is its JSON
    name, and it hashes and compares as that string."""

    TEXEL = "texel"
    EDGEL = "edgel"
    TEXTURE = "texture"

    def __hash__(self) -> int:  # as the plain string's, so parts hash as they always have
        return str.__hash__(self)

    @classmethod
    def of_point(cls, code: int) -> "PartKind":
        """The part kind of a salient point code."""
        return cls.EDGEL if code == EDGEL else cls.TEXEL

    def _salient(self) -> None:
        if self is PartKind.TEXTURE:
            raise ValueError("a texture part has no salient points and no descriptor slots")

    @property
    def codes(self) -> tuple[int, ...]:
        """The salient point codes of this kind, the one that draws it first."""
        self._salient()
        return (EDGEL,) if self is PartKind.EDGEL else (BLOB, CORNER)

    @property
    def slots(self) -> slice:
        """Where its numbers lie in the 15-slot descriptor layout."""
        self._salient()
        return EDGEL_SLOTS if self is PartKind.EDGEL else slice(0, DESCRIPTOR)

    @property
    def size(self) -> int:
        return BINS if self is PartKind.TEXTURE else self.slots.stop - self.slots.start

    def mask(self, records) -> Tensor:
        """(N, P) bool: the salient points of this kind in ``records`` (an ImageRecords)."""
        found = records.kind == self.codes[0]
        for code in self.codes[1:]:
            found = found | (records.kind == code)
        return records.mask & found
