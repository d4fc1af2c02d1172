"""Fuzz the config, the service's first entry point: any value at any key of the
example config, keys left out, unknown keys and sections of any name give a Config
or one ConfigError line, never another exception."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from companion.calibration import camera_model
from companion.config_load import ConfigError, config_from_dict
from tests.jsonfuzz import NewKey, fuzz_settings, json_values

EXAMPLE = Path(__file__).resolve().parents[1] / "systemd" / "config.example.toml"
BASE = tomllib.loads(EXAMPLE.read_text(encoding="utf-8"))


def _places(data: dict[str, Any], prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    """Every key path of the document: sections, subsections and values."""
    out = []
    for key, value in data.items():
        out.append((*prefix, key))
        if isinstance(value, dict):
            out += _places(value, (*prefix, key))
    return out


PLACES = _places(BASE)
# What a TOML file can hold (no None), and values near the edges of what the keys take.
toml_values = json_values.filter(lambda v: v is not None) | st.sampled_from(
    [
        0,
        -1,
        2**63 - 1,
        -(2**63),
        1e308,
        -1e-308,
        float("nan"),
        float("inf"),
        "",
        "x" * 300,
        "a\nb",
        "\r",
    ]
)


@fuzz_settings(400)
@given(
    edits=st.lists(
        st.tuples(
            st.sampled_from(PLACES),
            st.one_of(
                toml_values, st.just(KeyError), st.text(max_size=8).map(NewKey), st.text(max_size=8)
            ),
        ),
        min_size=1,
        max_size=4,
    )
)
def test_any_value_at_any_key_is_a_config_or_one_line(
    edits: list[tuple[tuple[str, ...], Any]],
) -> None:
    data = copy.deepcopy(BASE)
    for place, value in edits:
        parent = data
        for key in place[:-1]:
            child = parent.get(key)
            if not isinstance(child, dict):
                break
            parent = child
        else:
            if value is KeyError:
                parent.pop(place[-1], None)  # a key left out
            elif isinstance(value, NewKey):
                parent[str(value) or "k"] = {} if len(place) == 1 else 1  # unknown name
            else:
                parent[place[-1]] = value
    try:
        config = config_from_dict(data, Path("/nonexistent-base"))
        camera_model(config.camera)  # as load_config does
    except ConfigError as exc:
        assert str(exc) and "\n" not in str(exc)
