"""Declared, validated options for stages and writers.

Each option is declared once, as a dataclass field made by :func:`option`: name (the field
name), type, default, unit, rule and help. That one declaration validates values (in Python and
YAML alike), feeds ``o3d-terrain describe`` and generates the options table of the docs page.

Components are frozen keyword-only dataclasses made with :func:`component`; a bad component
cannot exist: construction raises :class:`~o3d_terrain.errors.ConfigError` listing every
problem at once, each naming the option, the owner, the rule and the value.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, ClassVar, Mapping, Sequence

from .errors import ConfigError, Problem, did_you_mean

_SPEC_KEY = "o3d_terrain.option"


# ---------------------------------------------------------------------------------------------
# rules


@dataclass(frozen=True)
class Range:
    """Numeric bounds; ``None`` means unbounded. Applies to every element of a tuple option."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False

    def check(self, value: float) -> bool:
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        if self.high is not None and (value >= self.high if self.high_open else value > self.high):
            return False
        return True

    def describe(self) -> str:
        if self.low is not None and self.high is not None:
            left = "(" if self.low_open else "["
            right = ")" if self.high_open else "]"
            return f"in {left}{_num(self.low)}, {_num(self.high)}{right}"
        if self.low is not None:
            return f"{'>' if self.low_open else '>='} {_num(self.low)}"
        if self.high is not None:
            return f"{'<' if self.high_open else '<='} {_num(self.high)}"
        return ""


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(float(x))


POSITIVE = Range(0, None, low_open=True)
NON_NEGATIVE = Range(0, None)
UNIT_INTERVAL = Range(0, 1)


# ---------------------------------------------------------------------------------------------
# option specification


@dataclass(frozen=True)
class OptionSpec:
    """What is declared about one option. ``kind`` is float, int, bool, str or 'path'."""

    name: str
    kind: Any
    default: Any
    help: str
    unit: str = ""
    rule: Range | None = None
    choices: tuple[str, ...] | None = None
    length: int | None = None  # a fixed-length tuple of ``kind``; ``None`` = a scalar
    broadcast: bool = False  # a scalar given for a tuple option fills every element
    nullable: bool = False
    required: bool = False
    check: Callable[[Any], str | None] | None = None  # extra rule; returns a message or None

    # -- description -------------------------------------------------------------------------
    def type_text(self) -> str:
        base = {float: "float", int: "int", bool: "bool", str: "string", "path": "path"}[self.kind]
        if self.choices:
            base = "one of " + ", ".join(repr(c) for c in self.choices)
        if self.length:
            base = f"{self.length} × {base}" + (" (or one value for all)" if self.broadcast else "")
        elif not self.choices:
            base = ("an " if base[0] in "aeiou" else "a ") + base
        if self.nullable:
            base += " or null"
        return base

    def rule_text(self) -> str:
        return self.rule.describe() if self.rule else ""

    def default_text(self) -> str:
        if self.required:
            return "(required)"
        if self.default is None:
            return "null"
        if isinstance(self.default, tuple):
            return "[" + ", ".join(_fmt(v) for v in self.default) + "]"
        return _fmt(self.default)

    # -- validation ------------------------------------------------------------------------------
    def coerce(self, value: Any, owner: str) -> Any:
        """Return the value in canonical form, or raise ValueError with a complete message."""
        if value is None:
            if self.nullable:
                return None
            raise ValueError(self._must(owner, value))
        if self.length is not None:
            if self.broadcast and not isinstance(value, (list, tuple)):
                value = [value] * self.length
            if not isinstance(value, (list, tuple)) or len(value) != self.length:
                raise ValueError(self._must(owner, value))
            out = tuple(self._scalar(v, owner, value) for v in value)
        else:
            out = self._scalar(value, owner, value)
        if self.check is not None:
            message = self.check(out)
            if message:
                raise ValueError(f"The '{self.name}' option of {owner} {message}. Got {value!r}.")
        return out

    def _scalar(self, v: Any, owner: str, whole: Any) -> Any:
        kind = self.kind
        ok = True
        if kind is float:
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            v = float(v) if ok else v
        elif kind is int:
            if isinstance(v, float) and v.is_integer():
                v = int(v)
            ok = isinstance(v, int) and not isinstance(v, bool)
        elif kind is bool:
            ok = isinstance(v, bool)
        elif kind is str:
            ok = isinstance(v, str) and (self.choices is None or v in self.choices)
        elif kind == "path":
            ok = isinstance(v, (str, Path)) and str(v) != ""
            v = str(v) if ok else v
        if ok and self.rule is not None and kind in (float, int):
            ok = self.rule.check(v)
        if not ok:
            message = self._must(owner, whole)
            if kind is str and self.choices and isinstance(v, str):
                hint = did_you_mean(v, self.choices)
                message += f" ({hint})" if hint else ""
            raise ValueError(message)
        return v

    def _must(self, owner: str, value: Any) -> str:
        what = self.type_text()
        rule = self.rule_text()
        if rule:
            what += f" {rule}"
        return f"The '{self.name}' option of {owner} must be {what}. Got {value!r}."


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return _num(v)
    if isinstance(v, str):
        return repr(v)
    return str(v)


def option(
    default: Any = dataclasses.MISSING,
    *,
    help: str,
    kind: Any = None,
    unit: str = "",
    rule: Range | None = None,
    choices: Sequence[str] | None = None,
    length: int | None = None,
    broadcast: bool = False,
    nullable: bool | None = None,
    check: Callable[[Any], str | None] | None = None,
) -> Any:
    """Declare an option as a dataclass field. ``kind`` defaults to the type of ``default``."""
    required = default is dataclasses.MISSING
    if kind is None:
        sample = default[0] if isinstance(default, tuple) and default else default
        if required or sample is None:
            raise TypeError("option(): give kind= when the default is missing or None")
        kind = type(sample)
    if isinstance(default, list):
        default = tuple(default)
    spec = OptionSpec(
        name="",  # filled in by component()
        kind=kind,
        default=None if required else default,
        help=help,
        unit=unit,
        rule=rule,
        choices=tuple(choices) if choices else None,
        length=length,
        broadcast=broadcast,
        nullable=(default is None) if nullable is None else nullable,
        required=required,
        check=check,
    )
    if required:
        return dataclasses.field(metadata={_SPEC_KEY: spec})
    return dataclasses.field(default=default, metadata={_SPEC_KEY: spec})


# ---------------------------------------------------------------------------------------------
# components: frozen, keyword-only, validated dataclasses


class Component:
    """Base of stages and writers. Subclasses are made with :func:`component`."""

    #: one stable name per component: the class name, used as YAML ``type:``
    type_name: ClassVar[str] = ""
    #: a one-line summary for ``o3d-terrain stages``
    summary: ClassVar[str] = ""
    #: the option names that hold input paths (resolved against a pipeline file's folder)
    path_options: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def options(cls) -> list[OptionSpec]:
        out = []
        for f in dataclasses.fields(cls):  # type: ignore[arg-type]
            spec = f.metadata.get(_SPEC_KEY)
            if spec is not None:
                out.append(dataclasses.replace(spec, name=f.name))
        return out

    @classmethod
    def option_names(cls) -> list[str]:
        return [o.name for o in cls.options()]

    @classmethod
    def check_config(cls, config: Mapping[str, Any], location: str = "") -> list[Problem]:
        """Every problem of a config mapping (without ``type``), without raising."""
        where = location or cls.type_name
        problems: list[Problem] = []
        names = cls.option_names()
        for key in config:
            if key not in names:
                hint = did_you_mean(str(key), names)
                problems.append(
                    Problem(where, f"unknown option '{key}'" + (f" ({hint})" if hint else ""),
                            "" if hint else f"options are: {', '.join(names)}")
                )
        for spec in cls.options():
            if spec.name in config:
                try:
                    spec.coerce(config[spec.name], cls.type_name)
                except ValueError as exc:
                    problems.append(Problem(where, str(exc)))
            elif spec.required:
                problems.append(
                    Problem(where, f"missing required option '{spec.name}'",
                            f"add '{spec.name}: ...' ({spec.help})")
                )
        if not problems:
            try:
                cls._construct(dict(config))
            except ConfigError as exc:  # cross-option rules from __post_init__
                problems += [Problem(where, p.message, p.fix) for p in exc.problems]
        return problems

    @classmethod
    def from_config(cls, config: Mapping[str, Any], location: str = "") -> "Component":
        """Build from a mapping of options (``type`` may be present and must match)."""
        config = {k: v for k, v in config.items() if k != "type"}
        problems = cls.check_config(config, location)
        if problems:
            raise ConfigError(problems)
        return cls._construct(config)

    @classmethod
    def _construct(cls, config: dict) -> "Component":
        return cls(**config)

    def to_config(self) -> dict:
        """The options as plain YAML-ready values, with ``type`` first."""
        out: dict[str, Any] = {"type": self.type_name}
        for spec in self.options():
            value = getattr(self, spec.name)
            out[spec.name] = list(value) if isinstance(value, tuple) else value
        return out

    def _validate(self) -> None:
        problems = []
        for spec in self.options():
            try:
                value = spec.coerce(getattr(self, spec.name), self.type_name)
            except ValueError as exc:
                problems.append(Problem(self.type_name, str(exc)))
            else:
                object.__setattr__(self, spec.name, value)
        if problems:
            raise ConfigError(problems)
        extra = self.check_options()
        if extra:
            raise ConfigError([Problem(self.type_name, m) for m in extra])

    def check_options(self) -> list[str]:
        """Rules that span several options; return messages (override in subclasses)."""
        return []

    def __post_init__(self) -> None:
        self._validate()


def component(registry: dict[str, type], summary: str = "") -> Callable[[type], type]:
    """Class decorator: make a frozen keyword-only validated dataclass and register it."""

    def wrap(cls: type) -> type:
        cls = dataclass(frozen=True, kw_only=True)(cls)
        cls.type_name = cls.__name__
        if summary:
            cls.summary = summary
        elif cls.__doc__:
            cls.summary = cls.__doc__.strip().splitlines()[0]
        generated_init = cls.__init__
        names = [f.name for f in dataclasses.fields(cls)]

        @functools.wraps(generated_init)
        def __init__(self, **kwargs: Any) -> None:
            unknown = [k for k in kwargs if k not in names]
            if unknown:
                raise ConfigError(
                    [
                        Problem(cls.__name__, f"unknown option '{k}'"
                                + (f" ({did_you_mean(k, names)})" if did_you_mean(k, names) else ""),
                                "" if did_you_mean(k, names) else f"options are: {', '.join(names)}")
                        for k in unknown
                    ]
                )
            missing = [
                n for n, f in cls.__dataclass_fields__.items()
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
                and n not in kwargs
            ]
            if missing:
                raise ConfigError(
                    [Problem(cls.__name__, f"missing required option '{m}'") for m in missing]
                )
            generated_init(self, **kwargs)

        cls.__init__ = __init__
        if cls.__name__ in registry:
            raise TypeError(f"{cls.__name__} is registered twice")
        registry[cls.__name__] = cls
        return cls

    return wrap
