"""Exceptions raised by o3d_terrain.

Library code raises; only the command-line interface catches and prints. Every message names
where the problem is (stage, option, file) and how to fix it.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Iterable, Sequence


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


class StageError(O3DTerrainError, RuntimeError):
    """A stage failed while running; the message starts with the stage name."""


def did_you_mean(name: str, candidates: Sequence[str]) -> str:
    """Return " (did you mean 'x'?)" for the closest candidate, or "" when none is close."""
    close = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.6)
    return f"did you mean '{close[0]}'?" if close else ""


class TerrainWarning(UserWarning):
    """Input the library can process but that is probably not what the caller meant (a cloud
    whose z axis is not up, coordinates float32 rounded by more than a centimetre); the
    message says what to check and how to fix it."""
