"""The error of the identification package: input data that cannot be used."""


class DataError(ValueError):
    """Raised for unusable input data, with a message saying what to fix."""
