"""The one exception type for user mistakes.

Every package raises :class:`UserInputError` for bad input a person can fix (unknown suite, malformed
file, wrong field); the CLI turns it into one clear line and a non-zero exit instead of a traceback.
It lives at the bottom of the import chain so that every package can raise it.
"""

from __future__ import annotations

from collections.abc import Iterable


class UserInputError(ValueError):
    """Bad input from the user: the message says which file/field and what was expected."""


def unknown_choice(kind: str, value: object, choices: Iterable[object]) -> UserInputError:
    """Build the error for a name that is not among the valid choices, listing them."""
    listed = ", ".join(str(c) for c in choices)
    return UserInputError(f"unknown {kind} {value!r}; expected one of: {listed}")
