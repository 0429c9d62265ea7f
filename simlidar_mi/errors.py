"""One exception base class for the whole library.

Every error a user can cause derives from :class:`SimlidarError`; messages name
the file, key and value at fault and, where possible, what would be valid.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any


class SimlidarError(Exception):
    """Base class of every error raised on purpose by simlidar_mi."""


class SimlidarWarning(UserWarning):
    """Something that probably makes a result wrong, without stopping the run; the CLI
    prints it as one line ``simlidar-mi CMD: warning: ...``."""


class ConfigError(SimlidarError, ValueError):
    """A scene file or parameter holds a value we cannot use.

    Parameters
    ----------
    message : what is wrong and what would be valid.
    file : the scene file, if any.
    key : dotted key path in the file (``scan.dtheta_deg``).
    value : the offending value.
    """

    def __init__(self, message: str, *, file: str | Path | None = None,
                 key: str | None = None, value: Any = None) -> None:
        self.reason = message  # the message without the file/key/value prefix
        self.file = str(file) if file is not None else None
        self.key = key
        self.value = value
        where = []
        if self.file:
            where.append(self.file)
        if key:
            where.append(f"key '{key}'")
        if key is not None or value is not None:
            where.append(f"value {value!r}")
        prefix = ": ".join([", ".join(where)]) + ": " if where else ""
        super().__init__(prefix + message)

    def __reduce__(self):
        # Keep file/key/value when a Dask worker's error is pickled back to the study.
        return (_config_error, (self.reason, self.file, self.key, self.value))


def _config_error(message: str, file: str | None, key: str | None, value: Any) -> ConfigError:
    return ConfigError(message, file=file, key=key, value=value)


class GrammarError(SimlidarError, ValueError):
    """A grammar or L-system string is malformed; carries the position."""

    def __init__(self, message: str, *, text: str | None = None,
                 position: int | None = None, source: str | None = None) -> None:
        self.text = text
        self.position = position
        self.source = source
        loc = ""
        if source:
            loc += f"{source}: "
        if position is not None:
            loc += f"at position {position}: "
        detail = ""
        if text is not None and position is not None:
            lo = max(0, position - 20)
            snippet = text[lo:position + 20]
            detail = f"\n  {snippet}\n  {' ' * (position - lo)}^"
        super().__init__(loc + message + detail)


class DerivationTooLarge(SimlidarError):
    """A derivation would exceed the configured module limit."""


class LLVMNotFound(SimlidarError, RuntimeError):
    """No libLLVM >= 17 could be found for Dr.Jit's llvm backend."""


class PhotoError(SimlidarError, ValueError):
    """A photograph cannot be read or classified."""


class OutputError(SimlidarError, OSError):
    """An output location cannot be used: not a folder, not writable, or in use by another run."""
