"""Errors of the eval library."""


class EvalInputError(ValueError):
    """Bad input to the evaluator: a malformed trajectory file, too few poses, no overlap in time, a degenerate
    alignment problem. The message names the file (where there is one) and the problem; the CLI prints it
    without a traceback and exits 2."""
