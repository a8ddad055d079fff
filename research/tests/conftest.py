"""The library tests' fixtures (tests/conftest.py), for the studies' tests too."""

from tests.conftest import short_episodes  # noqa: F401
