"""One-line warnings: what pedrl did about a problem it could work around, printed as ``pedrl: warning: <message>``.

Errors end a run in one line (:mod:`pedrl.cli`); a problem that a run works around (k-means shrinking K, a numba
cache rebuilt) is reported the same way, on stderr, instead of Python's two-line ``file:line: UserWarning`` form.
They are ordinary warnings of the category :class:`PedrlWarning`, so ``warnings`` filters and ``pytest.warns`` see
them; other warnings keep Python's format.
"""

from __future__ import annotations

import warnings

__all__ = ["PedrlWarning", "warn"]


class PedrlWarning(UserWarning):
    """A problem pedrl worked around; shown as one line, ``pedrl: warning: <message>``."""


def warn(message: str) -> None:
    """Issue ``message`` (its first line) as a :class:`PedrlWarning`."""
    _install_format()
    warnings.warn(message.splitlines()[0] if message else message, PedrlWarning, stacklevel=2)


def _install_format() -> None:
    """Print :class:`PedrlWarning` as one line; the format of every other warning is kept (installed once)."""
    original = warnings.formatwarning
    if getattr(original, "_pedrl", False):
        return

    def formatwarning(message, category, filename, lineno, line=None) -> str:
        if isinstance(category, type) and issubclass(category, PedrlWarning):
            return f"pedrl: warning: {message}\n"
        return original(message, category, filename, lineno, line)

    formatwarning._pedrl = True  # type: ignore[attr-defined]
    warnings.formatwarning = formatwarning
