"""Name -> class registries, filled by decorators and by package entry points."""

from __future__ import annotations

import pkgutil
from importlib import import_module
from importlib.metadata import entry_points

from uqflow.errors import StudyError


class Registry:
    """Classes by name; entry points of ``group`` are loaded on first lookup of a missing name."""

    def __init__(self, group: str, what: str, builtins: tuple[str, ...] = ()):
        self.group = group
        self.what = what
        self.builtins = builtins
        self._classes: dict[str, type] = {}
        self._entry_points_loaded = False
        self._broken: dict[str, str] = {}

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
        # Built-ins also resolve from a source checkout that was never pip-installed: every
        # module of a built-in package is imported, so its decorators register it and adding
        # one touches no list here.
        for package in self.builtins:
            for module in _package_modules(package):
                try:
                    import_module(module)
                except ImportError:
                    pass
        for ep in entry_points(group=self.group):
            if ep.name in self._classes:
                continue
            try:
                cls = ep.load()
            except Exception as exc:  # one broken plug-in must not hide the others
                self._broken[ep.name] = f"{type(exc).__name__}: {exc}"
                continue
            self._classes.setdefault(ep.name, cls)
            if not getattr(cls, "name", ""):
                cls.name = ep.name

    def _import_named(self, name: str) -> None:
        """Import the built-in module named after ``name`` alone (``solvers.mpm`` for "mpm",
        ``uqflow.methods.monte_carlo`` for "monte-carlo"), where most names register: every
        built-in module imported is a second per process (the solvers' numba modules), paid
        by each CLI run and each dask worker for one solver and one method."""
        module = name.replace("-", "_")
        if not module.isidentifier():
            return
        for package in self.builtins:
            try:
                import_module(f"{package}.{module}")
            except ImportError:
                pass

    def get(self, name: str) -> type:
        if name not in self._classes and not self._entry_points_loaded:
            self._import_named(name)
        if name not in self._classes:
            self._load_entry_points()
        try:
            return self._classes[name]
        except KeyError:
            if name in self._broken:
                raise StudyError(f"{self.what} '{name}' is installed but cannot be loaded "
                                 f"({self._broken[name]})") from None
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


def _package_modules(name: str) -> list[str]:
    """``name`` and, if it is a package, the modules and packages directly in it."""
    try:
        package = import_module(name)
    except ImportError:
        return []
    found = [name]
    for info in pkgutil.iter_modules(getattr(package, "__path__", [])):
        found.append(f"{name}.{info.name}")
    return found


#: Propagation methods by name (``uqflow.methods.register_method``). It lives here, not in
#: ``uqflow.methods``, so that the report layer finds a result's method without importing the
#: methods, which import the report layer; the built-ins register on the first lookup.
method_registry = Registry("uqflow.methods", "method", builtins=("uqflow.methods",))
