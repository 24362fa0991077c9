"""The two kinds of failure a user sees, and their exit codes (SPEC 8)."""


class InputError(Exception):
    """Bad input (scene, option, geometry): one-line message, exit code 2."""

    exit_code = 2


class SolverError(Exception):
    """The solver failed (divergence, NaN): one-line message, exit code 1."""

    exit_code = 1


class DataError(InputError, SolverError):
    """Scene data found bad during the run (not finite, or negative where it must not be).

    Bad input, exit code 2; raised inside the time loop, it stops the run as a solver
    failure does (``except SolverError``), keeping the output written so far.
    """

    exit_code = 2


class Interrupted(SolverError):
    """The run was stopped by a signal (Ctrl-C): exit code 128 + the signal number.

    A SolverError for the CLI (one line, everything written so far kept readable), with
    the shell's exit code of a process ended by that signal (130 for SIGINT).
    """

    def __init__(self, message: str, signal_number: int):
        super().__init__(message)
        self.exit_code = 128 + signal_number
