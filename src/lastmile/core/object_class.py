"""Object classes shared by perception, tracking, decision and the simulator's agents."""

from __future__ import annotations

from enum import IntEnum


class ObjectClass(IntEnum):
    """Integer ids so classes sit in numeric struct-of-arrays columns."""

    UNKNOWN = 0
    CAR = 1
    PEDESTRIAN = 2
    CYCLIST = 3
    ANIMAL = 4  # geese, dogs: small, slow and not to be run over

    @property
    def vulnerable(self) -> bool:
        """Road users the shuttle always yields to (WATonoBus: lowest priority against them)."""
        return self in (ObjectClass.PEDESTRIAN, ObjectClass.CYCLIST, ObjectClass.ANIMAL)
