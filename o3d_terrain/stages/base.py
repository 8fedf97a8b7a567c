"""Stage base classes and the stage registry.

A stage is a frozen keyword-only dataclass (made with :func:`stage`) whose options are declared
with :func:`o3d_terrain.options.option`. Calling a stage on a frame (or on any cloud that
:func:`~o3d_terrain.frame.as_frame` accepts) returns a new frame; the input is never modified.

Each stage declares what it reads and writes, so a pipeline can check the chain before any
point is read:

- ``reads``: products that an earlier stage must have made (e.g. ``("grid",)``);
- ``writes``: products it adds to the frame;
- ``writes_attributes``: per-point attributes it adds to the cloud (a source: those its first
  frame may carry, ``given_attributes()``, which a file reader answers per format).
"""

from __future__ import annotations

from typing import Any, Callable, ClassVar

from ..errors import InputError, StageError, reworded
from ..frame import Frame, as_frame
from ..options import Component, component

#: every registered stage by class name (the YAML ``type:``)
STAGES: dict[str, type["Stage"]] = {}


def stage(cls: type | None = None, *, summary: str = "") -> Any:
    """Class decorator: a frozen, keyword-only, validated, registered stage."""
    decorate: Callable[[type], type] = component(STAGES, summary)
    return decorate(cls) if cls is not None else decorate


class Stage(Component):
    """A processing step: ``frame = stage(frame)``."""

    reads: ClassVar[tuple[str, ...]] = ()
    writes: ClassVar[tuple[str, ...]] = ()
    writes_attributes: ClassVar[tuple[str, ...]] = ()
    is_source: ClassVar[bool] = False
    #: options for an example instance, when some options are required (contract tests, docs)
    example: ClassVar[dict[str, Any] | None] = None

    def __call__(self, data: Any = None) -> Frame:
        if self.is_source:
            return self._guard(self.read)
        frame = as_frame(data)
        missing = [p for p in self.reads if p not in frame.products]
        if missing:
            raise StageError(
                f"{self.type_name}: needs the product(s) {', '.join(missing)}, which no earlier "
                f"stage made; run {producers_text(missing[0])} before it"
            )
        return self._guard(lambda: self.run(frame))

    def _guard(self, call: Callable[[], Frame]) -> Frame:
        try:
            return call()
        except InputError as exc:
            text = str(exc)
            if not text.startswith(self.type_name):  # of its kind (NotACloudError)
                raise reworded(exc, f"{self.type_name}: {text}") from exc
            raise

    def run(self, frame: Frame) -> Frame:  # pragma: no cover - abstract
        raise NotImplementedError

    def read(self) -> Frame:  # pragma: no cover - abstract, sources only
        raise NotImplementedError


class SourceStage(Stage):
    """A stage that makes the first frame (a file reader, a stereo pair, a synthetic scene)."""

    is_source: ClassVar[bool] = True

    def given_attributes(self) -> tuple[str, ...] | None:
        """The per-point attributes the first frame may carry besides ``positions`` (what a
        pipeline checks the attributes its writers name against); None when only the data
        can tell."""
        return self.writes_attributes


def producers_text(product: str) -> str:
    names = [name for name, cls in STAGES.items() if product in cls.writes]
    return " or ".join(names) if names else f"a stage that writes '{product}'"
