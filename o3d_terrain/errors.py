"""Exceptions raised by o3d_terrain.

Library code raises; only the command-line interface catches and prints. Every message names
where the problem is (stage, option, file) and how to fix it.
"""

from __future__ import annotations

import difflib
import functools
import inspect
import os
import sys
import warnings
from dataclasses import dataclass
from typing import Callable, Iterable, Mapping, Sequence, TypeVar

_F = TypeVar("_F", bound=Callable)


class O3DTerrainError(Exception):
    """Base class of every error this package raises on purpose."""


@dataclass(frozen=True)
class Problem:
    """One configuration problem: where it is, what is wrong, and how to fix it."""

    location: str
    message: str
    fix: str = ""

    def __str__(self) -> str:
        text = f"{self.location}: {self.message}" if self.location else self.message
        return f"{text} ({self.fix})" if self.fix else text


class ConfigError(O3DTerrainError, ValueError):
    """A stage, option or pipeline file is invalid. Carries every problem found, not just the first.

    The command-line interface maps it to exit code 2.
    """

    def __init__(self, problems: Iterable[Problem] | Problem | str):
        if isinstance(problems, (Problem, str)):
            problems = [problems]
        self.problems: list[Problem] = [
            p if isinstance(p, Problem) else Problem("", str(p)) for p in problems
        ]
        super().__init__(self._text())

    def _text(self) -> str:
        if len(self.problems) == 1:
            return str(self.problems[0])
        lines = [f"{len(self.problems)} problems:"]
        lines += [f"  - {p}" for p in self.problems]
        return "\n".join(lines)


class InputError(O3DTerrainError, ValueError):
    """The data given to a stage cannot be processed (empty cloud, too few valid cells, bad file)."""


class NotACloudError(InputError):
    """A file that holds no point cloud at all (a KITTI sequence's ``calib.txt`` or
    ``times.txt``, a ``.npy`` array that is not (N, 3) or (N, 4), a file with no points), as
    against a cloud file cut short or corrupt, which is a plain :class:`InputError`.
    ``o3d-terrain run`` skips such a file of a folder it was given instead of failing it.

    ``path`` is the file and ``reason`` what is wrong with it; the message is
    "{path}: {reason}" with whatever a stage or the pipeline puts before it
    (:func:`reworded` keeps both attributes)."""

    def __init__(self, path: str | os.PathLike, reason: str):
        super().__init__(f"{os.fspath(path)}: {reason}")
        self.path = os.fspath(path)
        self.reason = reason

    def __reduce__(self):  # pickled and copied as it is, reworded or not
        return _with_message, (type(self), str(self), dict(self.__dict__))


class StageError(O3DTerrainError, RuntimeError):
    """A stage failed while running; the message starts with the stage name."""


_E = TypeVar("_E", bound=BaseException)


def reworded(exc: _E, message: str) -> _E:
    """An exception of the type of ``exc``, with its attributes, whose message is
    ``message``: how a stage or the pipeline says where an error happened without changing
    its kind (a :class:`NotACloudError` stays one, with its ``path`` and ``reason``)."""
    return _with_message(type(exc), message, exc.__dict__)


def _with_message(cls: type[_E], message: str, state: Mapping[str, object]) -> _E:
    exc = cls.__new__(cls, message)  # BaseException.__new__ sets args; __init__ is skipped
    exc.__dict__.update(state)
    return exc


def did_you_mean(name: str, candidates: Sequence[str], n: int = 1) -> str:
    """Return "did you mean 'x'?" for the closest candidate ("did you mean 'x', 'y' or 'z'?"
    for the ``n`` closest), or "" when none is close."""
    close = [f"'{c}'" for c in difflib.get_close_matches(name, list(candidates), n=n,
                                                          cutoff=0.6)]
    if not close:
        return ""
    return "did you mean " + (close[0] if len(close) == 1 else
                              ", ".join(close[:-1]) + f" or {close[-1]}") + "?"


def checked_keywords(hints: Mapping[str, str] | None = None) -> Callable[[_F], _F]:
    """Decorator for the public functions that take many keyword options: a call with a
    keyword the function does not take raises the ``TypeError`` Python would, naming the
    closest keywords it does take (up to 3, "did you mean ...?") or, for a keyword in
    ``hints``, what the hint says (an option of Open3D's ``segment_plane`` with no
    counterpart here, say). Calls with known keywords go straight through (one set
    difference)."""

    def decorate(func: _F) -> _F:
        names = frozenset(inspect.signature(func).parameters)
        known = sorted(names)

        @functools.wraps(func)
        def checked(*args, **kwargs):
            unknown = kwargs.keys() - names
            if unknown:
                raise TypeError(_unknown_keywords(func.__name__, sorted(unknown), known, hints))
            return func(*args, **kwargs)

        return checked  # type: ignore[return-value]

    return decorate


def _unknown_keywords(function: str, unknown: Sequence[str], known: Sequence[str],
                      hints: Mapping[str, str] | None) -> str:
    """The message of :func:`checked_keywords`: per unknown keyword, its hint or the closest
    known ones; the whole list of known ones once when some unknown keyword is close to none."""
    lines = []
    listed = False
    for name in unknown:
        text = f"{function}() got an unexpected keyword argument '{name}'"
        close = did_you_mean(name, known, n=3)
        if hints and name in hints:
            text += f": {hints[name]}"
        elif close:
            text += f"; {close}"
        else:
            listed = True
        lines.append(text)
    if listed:
        lines.append(f"{function}() takes {', '.join(known)}")
    return "; ".join(lines)


class TerrainWarning(UserWarning):
    """Input the library can process but that is probably not what the caller meant (a cloud
    whose z axis is not up, coordinates float32 rounded by more than a centimetre); the
    message says what to check and how to fix it."""


_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


def warn(message: str) -> None:
    """Issue a :class:`TerrainWarning` attributed to the caller's first line outside this
    package (the call to ``segment_terrain``, a stage or a pipeline in the user's code), not
    to whichever library line noticed the problem: the location Python prints is then the
    caller's, and its default filter shows the warning once per line of the caller's code."""
    frame = sys._getframe(1)
    level = 2  # warnings.warn's stacklevel of the frame that called warn()
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE_DIR):
        frame = frame.f_back
        level += 1
    warnings.warn(message, TerrainWarning, stacklevel=level)
