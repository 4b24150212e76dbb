"""Shared test configuration. ``HYPOTHESIS_PROFILE=thorough`` runs 10x more examples."""

import os

import pytest
from hypothesis import settings

settings.register_profile("default", derandomize=False)
settings.register_profile("thorough", max_examples=600, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@pytest.hookimpl(tryfirst=True)  # before xdist reads the groups
def pytest_collection_modifyitems(config, items):
    """The PX4 tier's scenarios share one flight per backend: every test of one backend
    goes to the same worker (``--dist loadgroup``), the two backends to either."""
    for item in items:
        backend = getattr(getattr(item, "callspec", None), "params", {}).get("flight")
        if backend is not None:
            item.add_marker(pytest.mark.xdist_group(f"tier-{backend}"))
