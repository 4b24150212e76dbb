"""Shared test configuration. ``HYPOTHESIS_PROFILE=thorough`` runs 10x more examples."""

import os

from hypothesis import settings

settings.register_profile("default", derandomize=False)
settings.register_profile("thorough", max_examples=600, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))
