"""One registry, one rule: what the package and its users attach to a key — an effect to its name, a screen or starts
to an effect's class, an export format to its name.

- **Registering** under a key that has an entry already raises ``ValueError`` naming the key and what it holds,
  unless ``replace=True``:
  nothing is overwritten by accident, a built-in entry included.
- **Unregistering** removes a user's entry; where it had replaced a built-in one, the built-in entry is back. A
  built-in entry itself is not removed (``ValueError``): replace it instead.
- **Looking up** a class walks its method resolution order (:meth:`Registry.find`): a subclass has its parent's entry
  unless it registers its own. A registry keyed by the effects' classes (``by_class``) takes an effect instance for
  its class wherever it takes a key.

The package's own entries are marked built in by :meth:`Registry.seal` once its modules have registered them."""
from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

__all__ = ["Registry"]


def _name(key) -> str:
    return key.__name__ if isinstance(key, type) else repr(key)


class Registry(Mapping):
    """Entries by key (read as a mapping); ``what`` names an entry in the messages (``"screen"``, ``"effect"``);
    ``by_class``: keyed by classes, an instance standing for its class."""

    def __init__(self, what: str, *, by_class: bool = False):
        self.what = what
        self.by_class = by_class
        self._entries: dict = {}
        self._built_in: dict = {}

    def key(self, key):
        """``key`` as this registry keys it (an instance's class, for a registry ``by_class``)."""
        return type(key) if self.by_class and not isinstance(key, type) else key

    def add(self, key, value, *, replace: bool = False) -> None:
        """``value`` under ``key``; a key with an entry already needs ``replace=True``."""
        key = self.key(key)
        if key in self._entries and not replace:
            old = self._entries[key]
            taken = (f"{key.__name__} has its {self.what} registered already" if isinstance(key, type)
                     else f"{self.what} {key!r} is registered already")
            raise ValueError(f"{taken} ({type(old).__name__}{', built in' if self.is_built_in(key) else ''}); "
                             "replace=True replaces it")
        self._entries[key] = value

    def remove(self, key) -> None:
        """Take ``key``'s entry away: a user's is removed (nothing happens where there is none), a replaced built-in
        entry comes back, a built-in entry is kept (``ValueError``)."""
        key = self.key(key)
        if key in self._built_in:
            if self._entries.get(key) is self._built_in[key]:
                which = f"{key.__name__}'s {self.what}" if isinstance(key, type) else f"{self.what} {key!r}"
                raise ValueError(f"{which} is built in and cannot be removed; register another with replace=True to "
                                 "replace it")
            self._entries[key] = self._built_in[key]
        else:
            self._entries.pop(key, None)

    def seal(self) -> None:
        """Mark every entry registered so far as built in (the package calls it once its own are registered)."""
        self._built_in = dict(self._entries)

    def is_built_in(self, key) -> bool:
        """Whether ``key``'s entry is the package's own (not a user's, nor a user's replacement)."""
        return key in self._built_in and self._entries.get(key) is self._built_in[key]

    def find(self, cls, default: Any = None) -> Any:
        """The entry of the class ``cls`` (or an instance's class) or its nearest parent; ``default`` where none has
        one."""
        for c in (cls if isinstance(cls, type) else type(cls)).__mro__:
            if c in self._entries:
                return self._entries[c]
        return default

    def __getitem__(self, key):
        return self._entries[key]

    def __iter__(self) -> Iterator:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"Registry({self.what!r}: {', '.join(_name(k) for k in self._entries)})"
