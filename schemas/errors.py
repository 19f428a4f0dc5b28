"""The errors a user sees and the exit code each one ends a command with.

Every `worldline` command ends with one of these codes (README, "Exit codes"):

    0 done, 1 partial, 2 invalid input, 3 not built, 4 busy (lock timeout),
    5 environment (disk full, corrupt warehouse), 130 interrupted (143 after SIGTERM).

Stage code raises a `WorldlineError` subclass with a one-line message naming the file and the
problem; the CLI prints the message alone and exits with the class's code.
"""

from __future__ import annotations

EXIT_DONE = 0
EXIT_PARTIAL = 1
EXIT_INVALID = 2
EXIT_NOT_BUILT = 3
EXIT_BUSY = 4
EXIT_ENVIRONMENT = 5
EXIT_INTERRUPTED = 130


class WorldlineError(RuntimeError):
    """One line for the user: the file and the problem."""

    exit_code = EXIT_PARTIAL


class InvalidInput(WorldlineError, ValueError):
    """The user's input (a file, a parameter) is wrong: fix it and run again."""

    exit_code = EXIT_INVALID


class NotBuilt(WorldlineError):
    """A step this one needs has not been run yet."""

    exit_code = EXIT_NOT_BUILT


class StepMissing(NotBuilt, FileNotFoundError):
    """What this step reads was never made ("run `worldline tokenize` first"); a
    FileNotFoundError too, so whatever handles a missing file handles it."""


class Busy(WorldlineError):
    """Another process holds what this one needs to write, past the wait allowed."""

    exit_code = EXIT_BUSY


class EnvironmentFault(WorldlineError):
    """The machine, not the input: a full disk, a corrupt warehouse, a file changed behind
    lineage's back."""

    exit_code = EXIT_ENVIRONMENT


class TamperedArtifact(EnvironmentFault):
    """A file's bytes no longer match the sha256 lineage recorded for it."""
