"""Errors of the inpaint library."""


class InpaintInputError(ValueError):
    """Bad input to an inpainting method (dtype, shape, all-hole or all-NaN map, bad option).

    The message says what was wrong and what was expected; the CLI shows it without a traceback.
    """
