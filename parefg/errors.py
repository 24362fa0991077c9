"""The two kinds of failure a user sees, and their exit codes (SPEC 8)."""


class InputError(Exception):
    """Bad input (scene, option, geometry): one-line message, exit code 2."""

    exit_code = 2


class SolverError(Exception):
    """The solver failed (divergence, NaN): one-line message, exit code 1."""

    exit_code = 1
