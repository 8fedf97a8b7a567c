import dataclasses

import pytest

from o3d_terrain.errors import ConfigError
from o3d_terrain.options import POSITIVE, Component, Range, component, option

REGISTRY: dict = {}


@component(REGISTRY)
class Example(Component):
    """An example component."""

    size: float = option(1.0, unit="m", rule=POSITIVE, help="a size")
    count: int = option(3, rule=Range(1, 10), help="a count")
    mode: str = option("fast", choices=("fast", "exact"), help="a mode")
    pair: tuple = option((5, 5), kind=int, length=2, broadcast=True, rule=Range(1, None), help="x")
    flag: bool = option(False, help="a flag")


def test_defaults_and_coercion():
    e = Example(size=2, pair=7)
    assert e.size == 2.0 and isinstance(e.size, float)
    assert e.pair == (7, 7)
    assert Example(pair=[3, 4]).pair == (3, 4)


def test_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        Example().size = 3


@pytest.mark.parametrize(
    "kwargs,text",
    [
        ({"size": -1}, "The 'size' option of Example must be a float > 0. Got -1."),
        ({"count": 11}, "The 'count' option of Example must be an int in [1, 10]. Got 11."),
        ({"count": True}, "must be an int"),
        ({"mode": "fats"}, "did you mean 'fast'?"),
        ({"pair": (1, 2, 3)}, "must be 2 × int"),
        ({"flag": "yes"}, "must be a bool"),
        ({"size": float("nan")}, "must be a float"),
    ],
)
def test_invalid_values_name_option_owner_rule_and_value(kwargs, text):
    with pytest.raises(ConfigError) as info:
        Example(**kwargs)
    assert text in str(info.value)


def test_unknown_option_suggests():
    with pytest.raises(ConfigError, match=r"unknown option 'siz' \(did you mean 'size'\?\)"):
        Example(siz=1)


def test_all_problems_reported_at_once():
    problems = Example.check_config({"size": 0, "count": 0, "colour": 1})
    assert len(problems) == 3


def test_config_round_trip():
    e = Example(size=0.5, mode="exact", pair=(2, 3))
    assert Example.from_config(e.to_config()) == e
