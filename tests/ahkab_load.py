"""Ahkab 0.18 (2015, the `bench` extra) on current SciPy and NumPy: the shims it needs, applied only where it is used
(tests/test_skin_netlist.py, benchmarks/bench_sensitivity_ahkab.py)."""

from __future__ import annotations

import contextlib
import io
import os
import warnings


def import_ahkab():
    """ahkab, imported quietly: its window imports moved to scipy.signal.windows, and its per-element report (which
    calls float() on a 1x1 array, and which nothing here reads) skipped."""
    import scipy.signal
    import scipy.signal.windows

    for name in ("bartlett", "hann", "hamming", "blackman", "blackmanharris", "gaussian", "kaiser"):
        if not hasattr(scipy.signal, name):
            setattr(scipy.signal, name, getattr(scipy.signal.windows, name))
    # ahkab's __init__ probes for a display by os.system('python -c "import matplotlib.pyplot ..."'): where the
    # `python` on PATH lacks matplotlib, that child prints a traceback on file descriptor 2, which redirect_stderr
    # does not reach; the descriptor itself goes to /dev/null for the import
    saved_fd2, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 2)
    try:
        with (
            contextlib.redirect_stdout(io.StringIO()),
            contextlib.redirect_stderr(io.StringIO()),
            warnings.catch_warnings(),
        ):
            warnings.simplefilter("ignore", DeprecationWarning)  # its transient module imports `imp`
            import ahkab
            from ahkab import results
    finally:
        os.dup2(saved_fd2, 2)
        os.close(saved_fd2)
        os.close(devnull)
    results.op_solution._get_elements_op = lambda self, circ, x: ([], {}, 0.0)
    results.op_solution.write_to_file = lambda self, *a, **k: None
    return ahkab
