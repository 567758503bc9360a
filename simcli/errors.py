"""Exit codes of the user-facing contract and the exceptions that carry them."""

from __future__ import annotations

EXIT_OK = 0
EXIT_OTHER = 1
EXIT_USAGE = 2
EXIT_INVALID_SCENE = 65  # EX_DATAERR
EXIT_NUMERICAL = 70  # EX_SOFTWARE
EXIT_OUTPUT = 74  # EX_IOERR
EXIT_INTERRUPTED = 75  # EX_TEMPFAIL: checkpoint written, safe to requeue and --resume


class SimcliError(Exception):
    """Base class: an error with an exit code and a message meant for the user."""

    exit_code = EXIT_OTHER


class SceneError(SimcliError):
    """An invalid scene. ``lines`` holds one formatted line per problem."""

    exit_code = EXIT_INVALID_SCENE

    def __init__(self, lines: list[str]):
        self.lines = list(lines)
        super().__init__("\n".join(self.lines))


class NumericalError(SimcliError):
    """NaN/Inf or a blow-up detected by the per-frame guard."""

    exit_code = EXIT_NUMERICAL


class OutputError(SimcliError):
    """Output could not be written (disk full, unwritable folder, ...)."""

    exit_code = EXIT_OUTPUT


class Interrupted(SimcliError):
    """The run stopped on a signal after writing a checkpoint."""

    exit_code = EXIT_INTERRUPTED
