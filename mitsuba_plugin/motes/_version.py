"""The package's version, in a module of its own so that the modules that key caches by it (``ensemble``) need
not import the package's ``__init__``, which imports them."""

__version__ = "0.1.0"
