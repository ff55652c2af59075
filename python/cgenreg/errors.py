"""The exceptions the package raises: the library's own errors, with its messages.

Every message names what was wrong and, for a file, the file; a file format error also carries
``path``, ``field``, ``expected`` and ``found`` as attributes.
"""

from __future__ import annotations

from typing import Optional


class CgenregError(Exception):
    """Base class of every error the cgenreg library reports."""


class InvalidInput(CgenregError, ValueError):
    """Input that is well formed but cannot be used (an option's value, an array's shape,
    too few correspondences, ...)."""


class FormatError(CgenregError, ValueError):
    """A file whose content does not match its format."""

    def __init__(self, message: str, path: str, field: str, expected: str, found: str):
        super().__init__(message)
        self.path = path
        self.field = field
        self.expected = expected
        self.found = found


class FileError(CgenregError, OSError):
    """A file that could not be read or written (missing, a folder, no permission, ...)."""

    def __init__(self, message: str, path: str, os_errno: Optional[int] = None):
        # OSError(errno, strerror, filename) so that `e.errno` and `e.filename` are set
        if os_errno is not None:
            super().__init__(os_errno, message, path)
        else:
            super().__init__(message)
        self.path = path

    def __str__(self) -> str:  # the library's message, not OSError's "[Errno 2] ..." form
        return self.strerror if self.strerror else super().__str__()
