"""YAML pipelines: a source, stages in order, and outputs.

A pipeline file::

    source:                      # where the first frame comes from
      type: ReadCloud
      path: scan.laz             # relative paths resolve against this file's folder (those
                                 # given with --set or --input: the current folder)
    stages:
      - type: GridQuantize
        cell_size: 0.5
      - type: RationalBSplineTerrain
    outputs:                     # paths relative to the output folder
      - type: WriteCloud
        path: labelled.ply
    output_dir: out              # optional; --output on the command line wins

The whole file is checked before any point is read, and every problem is reported at once with
its location and a fix (:class:`~o3d_terrain.errors.ConfigError`).
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Collection, Iterable, Iterator, Mapping, Sequence

import yaml

from .errors import ConfigError, O3DTerrainError, Problem, StageError, did_you_mean, reworded
from .frame import Frame, as_frame
from .options import Component
from .stages import STAGES, SourceStage, Stage
from .stages.base import producers_text
from .writers import WRITERS, Writer

TOP_LEVEL_KEYS = ("source", "stages", "outputs", "output_dir", "description")
RESOLVED_NAME = "pipeline.resolved.yaml"


@dataclass(frozen=True)
class Pipeline:
    """A checked pipeline. Build it with :func:`load_pipeline` or :func:`parse_pipeline`, or
    directly from stage objects in Python."""

    stages: tuple[Stage, ...]
    source: SourceStage | None = None
    outputs: tuple[Writer, ...] = ()
    output_dir: Path | None = None
    description: str = ""

    def __post_init__(self) -> None:
        problems = [] if self.stages else [Problem("Pipeline", "has no stages", _no_stages_fix())]
        problems += check_chain(self.source, self.stages, self.outputs)
        if problems:
            raise ConfigError(problems)

    def run(self, data: Any = None, *, output_dir: str | Path | None = None) -> "RunResult":
        """Run on ``data`` (any cloud :func:`as_frame` accepts) or on the source, then write."""
        timings: dict[str, float] = {}
        start = time.perf_counter()
        if data is not None:
            frame = as_frame(data)
        elif self.source is not None:
            frame = _located(lambda: self.source(), f"source {self.source.type_name}")
            timings[f"source {self.source.type_name}"] = time.perf_counter() - start
        else:
            raise ConfigError(Problem("pipeline", "no input", "give a source in the file or --input"))
        for index, stage in enumerate(self.stages):
            t0 = time.perf_counter()
            frame = _located(lambda: stage(frame), f"stages[{index}] {stage.type_name}")
            timings[f"stages[{index}] {stage.type_name}"] = time.perf_counter() - t0
        written: list[Path] = []
        out = Path(output_dir) if output_dir is not None else self.output_dir
        if self.outputs or out is not None:
            out = out if out is not None else Path("out")
            out.mkdir(parents=True, exist_ok=True)
            failed: list[O3DTerrainError] = []
            for index, writer in enumerate(self.outputs):
                try:  # one output's error (a misspelt attribute) does not lose the others
                    written += _located(lambda: writer.write(frame, out),
                                        f"outputs[{index}] {writer.type_name}")
                except O3DTerrainError as exc:
                    failed.append(exc)
            resolved = out / RESOLVED_NAME
            resolved.write_text(yaml.safe_dump(self.to_config(), sort_keys=False))
            written.append(resolved)
            if failed:
                kept = (f" (the other outputs were written to {out}: "
                        f"{', '.join(p.name for p in written)})")
                if len(failed) == 1:
                    raise reworded(failed[0], f"{failed[0]}{kept}") from failed[0]
                raise StageError(f"{len(failed)} outputs failed: "
                                 + "; ".join(str(e) for e in failed) + kept) from failed[0]
        return RunResult(frame, written, timings, time.perf_counter() - start)

    def to_config(self) -> dict:
        config: dict[str, Any] = {}
        if self.description:
            config["description"] = self.description
        if self.source is not None:
            config["source"] = self.source.to_config()
        config["stages"] = [s.to_config() for s in self.stages]
        config["outputs"] = [w.to_config() for w in self.outputs]
        return config


@dataclass
class RunResult:
    frame: Frame
    written: list[Path] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    seconds: float = 0.0

    def __repr__(self) -> str:
        return (f"RunResult({len(self.frame.positions)} points, products "
                f"{sorted(self.frame.products)}, {len(self.written)} file(s) written, "
                f"{self.seconds:.2f} s)")


def _no_stages_fix() -> str:
    """The fix for a pipeline without stages, with the stages it can list (not sources)."""
    names = sorted(name for name, cls in STAGES.items() if not cls.is_source)
    return ("list at least one stage under 'stages:', e.g. '- type: GridQuantize'; stages "
            f"are: {', '.join(names)}")


def _located(call, location: str):
    """Run ``call``; prefix a failure's message with where in the pipeline it happened
    (``location`` ends with the stage's name, which a stage's own message starts with: it
    is said once); the error keeps its type and attributes (:func:`reworded`)."""
    try:
        return call()
    except ConfigError:
        raise
    except O3DTerrainError as exc:
        text = str(exc)
        name = location.rsplit(" ", 1)[-1] + ": "
        raise reworded(exc, f"{location}: {text.removeprefix(name)}") from exc
    except KeyError as exc:  # a missing product or attribute
        raise StageError(f"{location}: {exc.args[0] if exc.args else exc}") from exc


# ---------------------------------------------------------------------------------------------
# checking


def check_chain(
    source: SourceStage | None, stages: Sequence[Stage], outputs: Sequence[Writer], *,
    replaced_source: str | None = None,
) -> list[Problem]:
    """Problems in the order of stages: a product read before any stage makes it.
    ``replaced_source``: the type of the source the file names, when ``--input`` replaced it
    with ``source`` (the hint for a product only that source makes says so)."""
    problems = []
    available = set(source.writes) if source is not None else set()
    for index, stage in enumerate(stages):
        if stage.is_source:
            problems.append(Problem(f"stages[{index}] {stage.type_name}",
                                    "is a source stage and cannot run after the first frame",
                                    "move it to 'source:'"))
        for product in stage.reads:
            if product not in available:
                message, fix = _missing_product(product, source, replaced_source, "stage")
                problems.append(Problem(
                    f"stages[{index}] {stage.type_name}",
                    f"needs the product '{product}', which no earlier stage makes{message}",
                    fix or f"add {producers_text(product)} before it"))
        available |= set(stage.writes)
    for index, writer in enumerate(outputs):
        for product in writer.required_products():
            if product not in available:
                made = ", ".join(sorted(available)) or "none"
                hint = did_you_mean(product, sorted(available))
                message, fix = _missing_product(product, source, replaced_source, "output")
                problems.append(Problem(
                    f"outputs[{index}] {writer.type_name}",
                    f"writes the product '{product}', which no stage makes{message} "
                    f"(products: {made})",
                    hint or fix or f"add {producers_text(product)} to the stages"))
    problems += _check_attributes(source, stages, outputs, replaced_source)
    return problems


def _check_attributes(source: SourceStage | None, stages: Sequence[Stage],
                      outputs: Sequence[Writer], replaced_source: str | None) -> list[Problem]:
    """Problems of the per-point attributes the writers name (``color_by``, ``attribute``)
    that neither the source nor any stage gives. Unchecked when only the data can tell what
    the cloud carries: a PLY or PCD file, a cloud given to :meth:`Pipeline.run`."""
    given = source.given_attributes() if source is not None else None
    if given is None:
        return []
    attributes = _attributes(given, stages)
    problems = []
    for index, writer, option_name, attribute in _named_attributes(outputs, attributes):
        hint = did_you_mean(attribute, attributes)
        message, fix = _missing_product(attribute, source, replaced_source, "output",
                                        declared="writes_attributes")
        makers = [name for name, cls in STAGES.items()
                  if attribute in cls.writes_attributes and not cls.is_source]
        problems.append(Problem(
            f"outputs[{index}] {writer.type_name}",
            f"{option_name} '{attribute}' is not a per-point attribute the source "
            f"{source.type_name} or a stage gives{message} (attributes: "
            f"{', '.join(attributes)})",
            hint or fix or (f"add {' or '.join(makers)} to the stages" if makers else
                            "name one of the attributes listed")))
    return problems


def _named_attributes(outputs: Sequence[Writer],
                      known: Collection[str]) -> Iterator[tuple[int, Writer, str, str]]:
    """(index, writer, option name, attribute) of each per-point attribute the writers name
    (``color_by``, ``attribute``) that is not in ``known``, in the order of the outputs and
    of each writer's options."""
    for index, writer in enumerate(outputs):
        for option_name, attribute in writer.required_attributes().items():
            if attribute not in known:
                yield index, writer, option_name, attribute


def _attributes(given: Iterable[str], stages: Sequence[Stage]) -> list[str]:
    """The per-point attributes of the cloud the writers get: ``positions``, those the source
    ``given``, and those the stages write; sorted."""
    return sorted({"positions", *given}.union(*(s.writes_attributes for s in stages)))


def unchecked_attributes(pipeline: Pipeline) -> list[str]:
    """The attributes the writers name that only the data can confirm, when the source's
    cloud may carry any (a PLY or PCD file, no source): those no stage writes, each as
    "outputs[i] Writer: option 'name'" with a did-you-mean of the stages' attributes when
    one is close. Empty when :func:`check_chain` checked them all."""
    if pipeline.source is not None and pipeline.source.given_attributes() is not None:
        return []
    written = _attributes((), pipeline.stages)
    found = []
    for index, writer, option_name, attribute in _named_attributes(pipeline.outputs, written):
        hint = did_you_mean(attribute, written)
        found.append(f"outputs[{index}] {writer.type_name}: {option_name} '{attribute}'"
                     + (f" ({hint})" if hint else ""))
    return found


def _missing_product(product: str, source: SourceStage | None, replaced: str | None,
                     what: str, *, declared: str = "writes") -> tuple[str, str]:
    """(more message, fix) for a ``product`` that only source stages make (a stereo pair's
    ``disparity``), which cannot be added to the stages: keep or make such a source, or drop
    the ``what`` ("stage" or "output") that reads it; ("", "") when a stage makes it.
    ``declared``: "writes_attributes" for a per-point attribute."""
    makers = [name for name, cls in STAGES.items() if product in getattr(cls, declared)]
    if not makers or any(not STAGES[name].is_source for name in makers):
        return "", ""
    names = " or ".join(makers)
    if replaced in makers and source is not None:
        message = (f": it comes from the source {replaced}, which --input replaced with "
                   f"{source.type_name}")
        fix = (f"to run on a cloud file, drop this {what}; to keep the {replaced} source, "
               "run without --input")
        return message, fix
    current = f", and the source is {source.type_name}" if source is not None else \
        " and there is no source"
    return f": only the source {names} makes it{current}", \
        f"use {names} as 'source:', or drop this {what}"


def _build(
    registry: Mapping[str, type[Component]], item: Any, location: str, base_dir: Path | None,
    kind: str,
) -> tuple[Component | None, list[Problem]]:
    if not isinstance(item, Mapping):
        return None, [Problem(location, f"must be a mapping with 'type:' and options, got {item!r}")]
    type_name = item.get("type")
    if not isinstance(type_name, str):
        named = [k for k in item if isinstance(k, str) and k in registry]
        if "type" not in item and len(item) == 1 and named:
            # "- Segmenter: {threshold: 0.3}": the name as a key, its options nested under it
            return None, [Problem(location, f"has no 'type:' (the {kind} is named as a key, "
                                            f"'{named[0]}:')",
                                  f"write '- type: {named[0]}' with its options beside "
                                  "'type:', not nested under the name")]
        return None, [Problem(location, "has no 'type:'",
                              f"add 'type: <{kind}>' (one of {', '.join(sorted(registry))})")]
    cls = registry.get(type_name)
    where = f"{location} {type_name}"
    if cls is None:
        hint = did_you_mean(type_name, list(registry))
        return None, [Problem(where, f"unknown {kind} '{type_name}'" + (f" ({hint})" if hint else ""),
                              "" if hint else f"{kind}s are: {', '.join(sorted(registry))}")]
    options = {k: v for k, v in item.items() if k != "type"}
    problems = []
    for name in cls.path_options:
        value = options.get(name)
        if isinstance(value, str) and value:
            path = Path(value).expanduser()
            if not path.is_absolute() and base_dir is not None:
                path = base_dir / path
            options[name] = str(path)
            if not path.exists():
                problems.append(Problem(
                    where, f"input file '{value}' not found (looked for {path})",
                    "check the path" + ("" if Path(value).expanduser().is_absolute() else
                                        "; relative paths resolve against the pipeline "
                                        "file's folder")))
    problems += cls.check_config(options, where)
    if problems:
        return None, problems
    return cls.from_config(options, where), []


def _build_list(items: Any, key: str, registry, base_dir: Path | None, kind: str):
    """Build every item of a ``stages:``/``outputs:`` list; None marks an item that failed."""
    if items is None:
        return [], []
    if not isinstance(items, list):
        return [], [Problem(key, f"must be a list of {kind}s")]
    built, problems = [], []
    for index, item in enumerate(items):
        component, found = _build(registry, item, f"{key}[{index}]", base_dir, kind)
        problems += found
        built.append(component)
    return built, problems


def parse_pipeline(config: Any, *, base_dir: str | Path | None = None,
                   replaced_source: str | None = None) -> Pipeline:
    """Build a pipeline from a mapping (the parsed YAML). Raises ConfigError with every problem.
    ``replaced_source``: the type of the source the file names, when ``--input`` replaced it
    (for the hints)."""
    base = Path(base_dir) if base_dir is not None else None
    problems: list[Problem] = []
    if not isinstance(config, Mapping):
        raise ConfigError(Problem("pipeline", "must be a mapping with 'stages:', got "
                                              f"{type(config).__name__}"))
    for key in config:
        if key not in TOP_LEVEL_KEYS:
            hint = did_you_mean(str(key), TOP_LEVEL_KEYS)
            problems.append(Problem("pipeline", f"unknown key '{key}'" + (f" ({hint})" if hint else ""),
                                    "" if hint else f"keys are: {', '.join(TOP_LEVEL_KEYS)}"))
    source = None
    if config.get("source") is not None:
        source, found = _build(STAGES, config["source"], "source", base, "stage")
        problems += found
        if source is not None and not source.is_source:
            problems.append(Problem(f"source {source.type_name}", "is not a source stage",
                                    "use ReadCloud, StereoToCloud or SyntheticScene"))
            source = None
    # a source that failed to build: what it would make is unknown, so the chain is not
    # checked against it (its own problem is the one to fix)
    source_failed = config.get("source") is not None and source is None
    stages, found = _build_list(config.get("stages"), "stages", STAGES, base, "stage")
    problems += found
    if "stages" not in config:
        problems.append(Problem("pipeline", "has no 'stages:'", _no_stages_fix()))
    elif config["stages"] is None or config["stages"] == []:
        problems.append(Problem("stages", "is empty: a pipeline runs at least one stage",
                                _no_stages_fix()))
    outputs, found = _build_list(config.get("outputs"), "outputs", WRITERS, None, "writer")
    problems += found
    if all(s is not None for s in stages) and all(w is not None for w in outputs) \
            and not source_failed:
        problems += check_chain(source, stages, outputs, replaced_source=replaced_source)
    output_dir = config.get("output_dir")
    if output_dir is not None and not isinstance(output_dir, str):
        problems.append(Problem("output_dir", f"must be a folder path, got {output_dir!r}"))
    if problems:
        raise ConfigError(problems)
    out = None
    if output_dir:
        out = Path(output_dir)
        out = out if out.is_absolute() or base is None else base / out
    return Pipeline(tuple(stages), source, tuple(outputs), out, str(config.get("description", "")))


class _DuplicateKey(yaml.constructor.ConstructorError):
    """A key given twice in one mapping of a pipeline file."""


class _UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that rejects a key given twice in one mapping (plain YAML keeps the
    last one silently: a second ``cell_size:`` would override the first unseen)."""

    def construct_mapping(self, node, deep=False):
        seen = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            try:
                first = seen.setdefault(key, key_node)
            except TypeError:  # an unhashable key: the base class reports it
                break
            if first is not key_node:
                raise _DuplicateKey(
                    "while reading a mapping", node.start_mark,
                    f"the key '{key}' is given twice (first on line "
                    f"{first.start_mark.line + 1})", key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


def read_yaml(path: str | Path) -> Any:
    """Parse a YAML file (safe loading; a key given twice in a mapping is an error); problems
    become ConfigError with line numbers."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(Problem(str(path), "no such pipeline file", "check the path"))
    if path.is_dir():
        raise ConfigError(Problem(str(path), "is a folder, not a pipeline file"))
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(Problem(str(path), f"cannot be read ({exc})")) from exc
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark else str(path)
        what = getattr(exc, "problem", None) or str(exc)
        fix = ("keep one of them" if isinstance(exc, _DuplicateKey)
               else "check indentation and that lists use '- '")
        raise ConfigError(Problem(where, f"invalid YAML: {what}", fix)) from exc


def apply_overrides(config: Any, overrides: Iterable[str]) -> Any:
    """Apply ``key.path=value`` overrides (``stages.1.cell_size=0.25``); values parse as YAML."""
    config = copy.deepcopy(config) if config is not None else {}
    problems = []
    for text in overrides:
        if "=" not in text:
            problems.append(Problem(f"--set {text}", "must look like KEY=VALUE",
                                    "e.g. --set stages.0.cell_size=0.25"))
            continue
        key, raw = text.split("=", 1)
        try:
            value = yaml.safe_load(raw) if raw.strip() else ""
        except yaml.YAMLError:
            value = raw
        parts = key.strip().split(".")
        node = config
        try:
            for i, part in enumerate(parts[:-1]):
                node = node[int(part)] if isinstance(node, list) else node.setdefault(part, {})
            last = parts[-1]
            if isinstance(node, list):
                node[int(last)] = value
            elif isinstance(node, dict):
                node[last] = value
            else:
                raise TypeError
        except (IndexError, ValueError, TypeError, KeyError, AttributeError):
            lists = {name: len(config[name]) for name in ("stages", "outputs")
                     if isinstance(config, dict) and isinstance(config.get(name), list)}
            counts = "; this file has " + ", ".join(
                f"{n} {name} (0 to {n - 1})" for name, n in lists.items()) if lists else ""
            problems.append(Problem(f"--set {text}",
                                    f"'{key}' does not name an option in this file{counts}",
                                    "use stages.<index>.<option>, e.g. stages.0.cell_size=0.25"))
    if problems:
        raise ConfigError(problems)
    return config


def _paths_from_here(config: dict, overrides: Iterable[str]) -> dict:
    """``config`` with the relative paths that ``overrides`` set (an input file option of the
    source or a stage, ``--set source.calibration=pair/calib.yaml``, or of a whole source or
    stage given as a mapping, or ``output_dir``) made absolute against the current folder,
    as ``--input`` is: a path typed on the command line means the same whichever folder the
    pipeline file lies in. Paths written in the file keep resolving against its folder;
    writers' paths stay relative to the output folder."""
    here = Path.cwd()

    def absolute(value: Any) -> Any:
        if not isinstance(value, str) or not value:
            return value
        path = Path(value).expanduser()
        return str(path if path.is_absolute() else here / path)

    def resolve(item: Any, names: Iterable[str] | None) -> None:
        if not isinstance(item, dict):
            return
        cls = STAGES.get(item.get("type")) if isinstance(item.get("type"), str) else None
        if cls is None:
            return
        for name in cls.path_options:
            if name in item and (names is None or name in names):
                item[name] = absolute(item[name])

    for text in overrides:
        key = text.split("=", 1)[0].strip()
        parts = key.split(".")
        if parts == ["output_dir"] and "output_dir" in config:
            config["output_dir"] = absolute(config["output_dir"])
        elif parts[0] == "source" and len(parts) <= 2:
            resolve(config.get("source"), parts[1:] or None)
        elif parts[0] == "stages" and 2 <= len(parts) <= 3 and parts[1].isdigit():
            stages = config.get("stages")
            if isinstance(stages, list) and int(parts[1]) < len(stages):
                resolve(stages[int(parts[1])], parts[2:] or None)
    return config


def load_pipeline(
    path: str | Path,
    *,
    overrides: Sequence[str] = (),
    input_path: str | Path | None = None,
) -> Pipeline:
    """Read, override, resolve and check a pipeline file. Relative paths in the file resolve
    against its folder; those given in ``overrides`` and ``input_path``, against the current
    folder."""
    path = Path(path)
    config = read_yaml(path)
    if config is None:
        raise ConfigError(Problem(str(path), "the pipeline file is empty", "add 'stages:'"))
    if not isinstance(config, dict):
        raise ConfigError(Problem(str(path), "must be a mapping with 'stages:'"))
    config = _paths_from_here(apply_overrides(config, overrides), overrides)
    replaced = None  # the source --input replaces
    if input_path is not None:  # a cloud file replaces whatever source the file names
        if not Path(input_path).exists():
            raise ConfigError(Problem("--input", f"'{input_path}' not found (looked for "
                                      f"{Path(input_path).resolve()})",
                                      "check the path; relative paths resolve against the "
                                      "current folder"))
        named = config.get("source")
        if isinstance(named, Mapping) and isinstance(named.get("type"), str):
            replaced = named["type"]
        config["source"] = {"type": "ReadCloud", "path": str(Path(input_path).resolve())}
    try:
        return parse_pipeline(config, base_dir=path.parent.resolve(), replaced_source=replaced)
    except ConfigError as exc:
        raise ConfigError([Problem(f"{path.name}: {p.location}" if p.location else path.name,
                                   p.message, p.fix) for p in exc.problems]) from None
