from dataclasses import dataclass, field

import pytest

from lastmile.core.config import from_mapping, load_toml
from lastmile.core.errors import ConfigError


@dataclass(frozen=True)
class Inner:
    rate_per_min: float = 1.0


@dataclass(frozen=True)
class Outer:
    name: str
    count: int = 2
    inner: Inner = field(default_factory=Inner)


def test_nested_tables_build_typed_configs():
    cfg = from_mapping(Outer, {"name": "a", "inner": {"rate_per_min": 3}}, "scenario")
    assert cfg == Outer(name="a", count=2, inner=Inner(3.0))


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"name": "a", "colour": 1}, "unknown key 'colour'"),
        ({}, "missing required key 'name'"),
        ({"name": "a", "count": "3"}, "scenario.count: expected an integer, got '3'"),
        ({"name": "a", "inner": {"rate_per_min": float("nan")}}, "expected a finite number"),
    ],
)
def test_bad_config_names_the_key_expected_and_got(data, message):
    with pytest.raises(ConfigError, match=message):
        from_mapping(Outer, data, "scenario")


def test_broken_toml_is_a_config_error(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text("name = ")
    with pytest.raises(ConfigError, match="expected valid TOML"):
        load_toml(p)
    with pytest.raises(ConfigError, match="no such file"):
        load_toml(tmp_path / "missing.toml")
