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
