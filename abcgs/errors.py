"""Exceptions that carry a message written for the user: what is wrong and what to do."""


class AbcgsError(Exception):
    """Base class of every user-facing error raised by abcgs."""


class InputError(AbcgsError, ValueError):
    """Bad input data: unreadable/corrupt images, mismatched sizes, empty masks, unknown labels."""


class ReconstructionError(AbcgsError, RuntimeError):
    """Structure from motion failed or registered too few images."""


class ParamsError(AbcgsError, ValueError):
    """``params.yaml`` does not match the schema."""


class NumericalError(AbcgsError, FloatingPointError):
    """A loss or parameter became NaN/Inf during optimisation."""
