"""Error types. User mistakes are one-line ``StudyError``; solver trouble is ``SolverError``."""

from __future__ import annotations


class UqflowError(Exception):
    """Base of every error uqflow raises on purpose."""


class StudyError(UqflowError):
    """A study (or its scene) cannot be run as written.

    The message is one line: ``<file>: <key>: <reason>``, so the CLI can print it as is.
    """

    def __init__(self, reason: str, *, file: str | None = None, key: str | None = None):
        self.file = file
        self.key = key
        self.reason = " ".join(str(reason).split())
        parts = [p for p in (file, key) if p]
        super().__init__(": ".join(parts + [self.reason]))

    def located(self, file: str) -> "StudyError":
        """The same error, now naming the study file it came from."""
        return type(self)(self.reason, file=self.file or file, key=self.key)


class SceneError(StudyError):
    """A solver's scene is invalid; ``key`` is the dotted scene key."""


class ResultFileError(UqflowError):
    """The result file could not be written mid-run (disk full, folder gone); the last good
    checkpoint is still on disk. One line, naming the file."""


class SolverError(UqflowError):
    """A realization failed inside the solver (diverged, non-physical state).

    The executor records it as a failed realization and the study goes on.
    """


class SolverUnavailable(UqflowError):
    """The solver could not run a realization at all (a remote model that cannot be reached):
    not the realization's failure. The study stops with the runs so far in its result file,
    that realization still pending, and ``--resume`` runs it once the solver is back."""


class AccuracyWarning(UserWarning):
    """An estimate may be inaccurate (large input C.V., unstable derivative, few samples)."""
