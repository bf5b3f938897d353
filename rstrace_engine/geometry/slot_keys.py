"""Stable host keys of a scene's items (meshes, materials, instances, lights): key -> slot,
with tombstoned slots reused lowest first (:class:`SlotKeys`)."""

from __future__ import annotations

from .elements import SceneError


class SlotKeys:
    """Stable host keys of one kind of item (key -> slot), with a free list of slots."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.slot: dict = {}
        self.free: list[int] = []  # tombstoned slots, reused lowest first

    def copy(self) -> SlotKeys:
        k = SlotKeys(self.kind)
        k.slot = dict(self.slot)
        k.free = list(self.free)
        return k

    def new_key(self, key, name: str | None, n: int):
        """The key for a new item: ``key`` if given (must be unused), else the name when it
        is unused, else a generated one."""
        if key is not None:
            try:
                hash(key)
            except TypeError:
                raise SceneError(f"{self.kind} '{name}': key {key!r} is not hashable") from None
            if key in self.slot:
                raise SceneError(f"{self.kind} '{name}': key {key!r} is already in use")
            return key
        if name is not None and name not in self.slot:
            return name
        k = n
        while f"{name or self.kind}#{k}" in self.slot:
            k += 1
        return f"{name or self.kind}#{k}"

    def place(self, items: list, item, key) -> int:
        """Put ``item`` in the lowest tombstoned slot of ``items`` (else a new one) under
        ``key``; returns the slot."""
        if self.free:
            self.free.sort()
            slot = self.free.pop(0)
            items[slot] = item
        else:
            slot = len(items)
            items.append(item)
        self.slot[key] = slot
        return slot

    def lookup(self, key) -> int:
        try:
            return self.slot[key]
        except (KeyError, TypeError):
            raise SceneError(f"{self.kind} '{key}': unknown key (no such {self.kind} in the "
                             f"scene)") from None
