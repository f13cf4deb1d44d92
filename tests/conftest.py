"""Safeguards for the whole test session."""

import signal
import warnings

import pytest


@pytest.fixture(autouse=True)
def _sigint_stays_deliverable(request):
    """The Ctrl-C tests send SIGINT to this process or to its children (which inherit its
    disposition and signal mask). A test whose libraries leave SIGINT ignored or blocked would
    make those tests fail far from the cause: restore it after each test and name the test."""
    yield
    handler = signal.getsignal(signal.SIGINT)
    blocked = signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    if handler is not signal.default_int_handler or blocked:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])
        warnings.warn(f"{request.node.nodeid} left SIGINT {'blocked' if blocked else repr(handler)}; restored")


#: The evaluation-harness files run last. In whole-suite runs after them, the three Ctrl-C tests
#: (test_limo_serial, test_mapping_run, test_serial_navigation) did not see their SIGINT, though
#: they pass after each of these files alone and SIGINT's handler and mask were intact after
#: each (probed); the cause is not found yet. Running these files last keeps the Ctrl-C tests in
#: the order they were verified in.
_LAST = ("test_baseline.py", "test_bench_paper.py", "test_bench_perf.py")


def pytest_collection_modifyitems(session, config, items):
    items.sort(key=lambda item: item.path.name in _LAST)      # stable: the order is kept otherwise
