"""Errors raised for bad input: one precise message naming the input, never a torch traceback."""


class InputError(ValueError):
    """An image, tensor, file or parameter given to ftorch cannot be used as it is."""


class NotFittedError(InputError, AttributeError):
    """A learner asked to answer, or to be saved for answering, before it has learned any class."""


class NewerSchema(InputError):
    """A file of a schema newer than this ftorch reads (:func:`ftorch.checkpoint.schema_of`)."""
