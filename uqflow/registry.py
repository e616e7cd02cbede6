"""Name -> class registries, filled by decorators and by package entry points."""

from __future__ import annotations

from importlib.metadata import entry_points

from uqflow.errors import StudyError


class Registry:
    """Classes by name; entry points of ``group`` are loaded on first lookup of a missing name."""

    def __init__(self, group: str, what: str):
        self.group = group
        self.what = what
        self._classes: dict[str, type] = {}
        self._entry_points_loaded = False

    def register(self, name: str):
        def decorator(cls):
            self._classes[name] = cls
            cls.name = name
            return cls
        return decorator

    def _load_entry_points(self) -> None:
        if self._entry_points_loaded:
            return
        self._entry_points_loaded = True
        for ep in entry_points(group=self.group):
            if ep.name not in self._classes:
                cls = ep.load()
                self._classes.setdefault(ep.name, cls)
                if getattr(cls, "name", None) in (None, ""):
                    cls.name = ep.name

    def get(self, name: str) -> type:
        if name not in self._classes:
            self._load_entry_points()
        try:
            return self._classes[name]
        except KeyError:
            known = ", ".join(sorted(self._classes)) or "none"
            raise StudyError(f"unknown {self.what} '{name}' (known: {known})") from None

    def names(self) -> list[str]:
        self._load_entry_points()
        return sorted(self._classes)

    def describe(self) -> dict[str, str]:
        """One-line description (first docstring line) of every registered class."""
        out = {}
        for name in self.names():
            doc = (self._classes[name].__doc__ or "").strip().splitlines()
            out[name] = doc[0] if doc else ""
        return out
