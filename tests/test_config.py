"""The strict TOML → frozen dataclass loader (tepinn_flight.config)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Literal

import pytest

from tepinn_flight.config import apply_overrides, check, from_dict, load_config, parse_override, to_dict
from tepinn_flight.errors import ConfigError


@dataclass(frozen=True)
class Inner:
    gain: float = 1.0
    label: str = "a"
    on: bool = False


@dataclass(frozen=True)
class Item:
    name: str
    weight: float = 0.0


@dataclass(frozen=True)
class Outer:
    count: int
    mode: Literal["fast", "slow"] = "fast"
    rate: float | None = None
    tags: tuple[str, ...] = ()
    pair: tuple[int, float] = (0, 0.0)
    inner: Inner = field(default_factory=Inner)
    items: tuple[Item, ...] = ()
    table: dict[str, float] = field(default_factory=dict)

    def __post_init__(self):
        check(self.count >= 0, f"'count' must be >= 0, got {self.count}")


def test_builds_nested_frozen_dataclasses_with_conversions():
    cfg = from_dict(Outer, {
        "count": 3, "mode": "slow", "rate": 5, "tags": ["x", "y"], "pair": [1, 2],
        "inner": {"gain": 2, "on": True}, "items": [{"name": "n1"}, {"name": "n2", "weight": 0.5}],
        "table": {"a": 1, "b": 2.5},
    })  # fmt: skip
    assert cfg == Outer(3, "slow", 5.0, ("x", "y"), (1, 2.0), Inner(2.0, "a", True),
                        (Item("n1"), Item("n2", 0.5)), {"a": 1.0, "b": 2.5})  # fmt: skip
    assert isinstance(cfg.rate, float) and isinstance(cfg.pair[1], float) and isinstance(cfg.inner.gain, float)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.count = 4  # type: ignore[misc]
    assert from_dict(Outer, {"count": 0}).rate is None  # omitted optional -> None


@pytest.mark.parametrize(
    "data, message",
    [
        ({"count": 1, "cuont": 2}, "unknown key 'cuont'"),
        ({"count": 1, "inner": {"gian": 2}}, "unknown key 'inner.gian'"),
        ({"count": 1, "items": [{"name": "a", "wieght": 1}]}, r"unknown key 'items\[0\].wieght'"),
        ({}, "missing key 'count'"),
        ({"count": 1.5}, "'count' must be an integer"),
        ({"count": True}, "'count' must be an integer"),
        ({"count": 1, "inner": {"gain": "big"}}, "'inner.gain' must be a number"),
        ({"count": 1, "inner": {"on": 1}}, "'inner.on' must be true or false"),
        ({"count": 1, "mode": "medium"}, "'mode' must be one of 'fast', 'slow'"),
        ({"count": 1, "tags": "x"}, "'tags' must be an array"),
        ({"count": 1, "tags": [1]}, r"'tags\[0\]' must be a string"),
        ({"count": 1, "pair": [1, 2, 3]}, "'pair' must have 2 elements"),
        ({"count": 1, "inner": 3}, "inner: expected a table"),
        ({"count": -1}, "'count' must be >= 0"),
    ],
)
def test_refuses_bad_input_naming_the_key(data, message):
    with pytest.raises(ConfigError, match=message):
        from_dict(Outer, data)


def test_load_config_file_errors_are_one_line(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("count = 2\n[inner]\ngain = inf\n")
    cfg = load_config(Outer, p)
    assert cfg.count == 2 and math.isinf(cfg.inner.gain)
    bad = tmp_path / "bad.toml"
    bad.write_text("count = = 2\n")
    with pytest.raises(ConfigError) as exc:
        load_config(Outer, bad)
    assert "invalid TOML" in str(exc.value) and "\n" not in str(exc.value) and str(bad) in str(exc.value)
    with pytest.raises(ConfigError, match="no such file"):
        load_config(Outer, tmp_path / "missing.toml")
    p.write_text("count = 2\nextra = 1\n")
    with pytest.raises(ConfigError, match="unknown key 'extra'") as exc:
        load_config(Outer, p)
    assert exc.value.path == str(p)


def test_overrides_use_toml_values_and_the_same_checks():
    cfg = from_dict(Outer, {"count": 1})
    new = apply_overrides(cfg, ["inner.gain=2.5", "mode=slow", "tags=['a', 'b']", "inner.label=word", "table.k=3"])
    assert new.inner.gain == 2.5 and new.mode == "slow" and new.tags == ("a", "b")
    assert new.inner.label == "word" and new.table == {"k": 3.0}
    assert cfg.inner.gain == 1.0  # the original is untouched
    assert parse_override("a.b = 1e-3") == (["a", "b"], 1e-3)
    for text, message in [
        ("inner.gian=1", "unknown key 'inner.gian'"),
        ("count.x=1", "'count' is not a table"),
        ("inner.gain=fast", "'inner.gain' must be a number"),
        ("count=-3", "'count' must be >= 0"),
        ("novalue", "not KEY=VALUE"),
    ]:
        with pytest.raises(ConfigError, match=message):
            apply_overrides(cfg, [text])


def test_to_dict_round_trips():
    cfg = from_dict(Outer, {"count": 2, "items": [{"name": "a"}], "rate": 3.0, "pair": [1, 2.0]})
    assert from_dict(Outer, to_dict(cfg)) == cfg
    assert "rate" not in to_dict(from_dict(Outer, {"count": 1}))  # None is omitted (TOML has no null)
