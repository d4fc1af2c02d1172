"""Any value a JSON document read back from disk can hold, for the fuzz tests of
saved state (json.loads reads NaN and the infinities too), and what every fuzz test
of an entry point shares."""

from __future__ import annotations

import os
from typing import Any

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

json_values: st.SearchStrategy[Any] = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=10),
    lambda inner: st.lists(inner, max_size=7) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=12,
)


def fuzz_settings(examples: int) -> Any:
    """The settings of a fuzz test of an entry point: ``examples`` in the default run,
    as many as ``FUZZ_N`` says by hand (FUZZ_N=5000 for a long search)."""
    return settings(
        max_examples=int(os.environ.get("FUZZ_N", str(examples))),
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    )


class NewKey(str):
    """A document edit that adds a key of this name beside the chosen one."""
