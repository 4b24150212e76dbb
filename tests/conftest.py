"""Shared test configuration. ``HYPOTHESIS_PROFILE=thorough`` runs 10x more examples."""

import os

import pytest
from hypothesis import settings

settings.register_profile("default", derandomize=False)
settings.register_profile("thorough", max_examples=600, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    """The library's example trajectory message, as a file."""
    from rota.cli import example_path

    path = tmp_path_factory.mktemp("cli") / "traj.json"
    path.write_text(example_path().read_text())
    return path


@pytest.hookimpl(tryfirst=True)  # before xdist reads the groups
def pytest_collection_modifyitems(config, items):
    """The PX4 tier's scenarios share one flight per backend: every test of one backend
    goes to the same worker (``--dist loadgroup``), the two backends to either. So do
    the tests of a module that share a module-scoped fixture."""
    for item in items:
        backend = getattr(getattr(item, "callspec", None), "params", {}).get("flight")
        if backend is not None:
            item.add_marker(pytest.mark.xdist_group(f"tier-{backend}"))
        elif _uses_a_module_fixture(item):
            # one worker for the module: its fixture (often a whole flight) is made once,
            # and tests that read what an earlier one flew find it
            item.add_marker(pytest.mark.xdist_group(f"module-{item.module.__name__}"))


def _uses_a_module_fixture(item) -> bool:
    info = getattr(item, "_fixtureinfo", None)
    return info is not None and any(defs[-1].scope == "module"
                                    for defs in info.name2fixturedefs.values() if defs)


@pytest.fixture(autouse=True)
def _sigint_as_a_terminal_gives_it():
    """Every test starts with Ctrl-C as a user's terminal gives it: Python's default
    handler, SIGINT not blocked in this thread. Processes a test starts inherit an
    ignored or blocked SIGINT from it, and then no Ctrl-C stops them: if an earlier
    test (or a library it loaded) left SIGINT so, it is put back, and said."""
    import signal
    import sys

    blocked = signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    handler = signal.getsignal(signal.SIGINT)
    if blocked or handler is not signal.default_int_handler:
        print(f"conftest: SIGINT was {'blocked' if blocked else 'unblocked'} with handler "
              f"{handler!r} before this test; restored", file=sys.stderr)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])
        signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
