"""Named classes that files and commands refer to: effects, drives, sensors, strategies.

One :class:`Registry` per extension point maps a name (an arm file's ``type``, an effect's name,
a search method) to a subclass of that point's abstract base; :meth:`Registry.register` adds a
class of one's own, so that arm files, fit files and commands can name it like the library's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Any, Generic, TypeVar

T = TypeVar("T")


class Registry(Mapping[str, type[T]], Generic[T]):
    """Name → class for the subclasses of ``base``; ``key(cls)`` is a class's name, ``classes``
    the library's own."""

    def __init__(self, what: str, base: type[T], key: Callable[[type[T]], str],
                 classes: Iterable[type[T]] = (), plural: str | None = None) -> None:
        self.what, self.base, self.key = what, base, key
        self.plural = plural or f"{what}s"
        self._classes: dict[str, type[T]] = {}
        for cls in classes:
            self.register(cls)

    def register(self, cls: type[T]) -> type[T]:
        """Add ``cls`` under its name (also as a class decorator); a name is taken once."""
        if not (isinstance(cls, type) and issubclass(cls, self.base)):
            raise TypeError(f"a {self.what} must subclass {self.base.__name__}, got {cls!r}")
        name = self.key(cls)
        if not (isinstance(name, str) and name.isidentifier()):
            raise ValueError(f"{self.what} class {cls.__name__} needs a name (an identifier), "
                             f"got {name!r}")
        if self._classes.get(name, cls) is not cls:
            raise ValueError(f"{self.what} name {name!r} is taken by "
                             f"{self._classes[name].__name__}")
        self._classes[name] = cls
        return cls

    def create(self, name: str, **settings: Any) -> T:
        """An instance by name; an unknown name or setting is refused with the known ones."""
        cls = self.lookup(name)
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(settings) - known)
        if unknown:
            raise ValueError(f"{name} {self.what}: unknown setting(s) {unknown}; settings: "
                             f"{sorted(known)}")
        return cls(**settings)

    def lookup(self, name: str) -> type[T]:
        """The class named ``name``, or a ValueError listing the known names."""
        if name not in self._classes:
            raise ValueError(f"unknown {self.what} {name!r}; {self.plural}: "
                             f"{sorted(self._classes)}")
        return self._classes[name]

    def copy(self) -> Registry[T]:
        """A registry with the same classes, to register others in without touching this one."""
        return Registry(self.what, self.base, self.key, self._classes.values(), self.plural)

    def __getitem__(self, name: str) -> type[T]:
        return self._classes[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._classes)

    def __len__(self) -> int:
        return len(self._classes)

    def __repr__(self) -> str:
        return f"Registry({self.what}: {sorted(self._classes)})"
