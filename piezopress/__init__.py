"""piezopress: open-loop force control of piezoelectric presses.

Architecture (imports go one way only, top to bottom)::

    piezocli/      command line (click): parses, calls pipelines, prints    (piezopress.piezocli)
    pipelines/     stages that read and write files: characterize, import, ...  (piezopress.pipelines)
    piezopress/acquisition/   protocols (plans, waveforms) and backends (virtual rig, DAQ)
    piezopress/analysis/      models, fits, metrics, diagnosis: pure math on numpy arrays
    piezopress/runformat.py   the Parquet run format (schema version 1)

``analysis`` never imports ``acquisition`` and neither imports ``pipelines`` or ``piezocli``.

Installed (``pip install .``), the folders ``piezocli/`` and ``pipelines/`` are the subpackages
``piezopress.piezocli`` and ``piezopress.pipelines`` (pyproject.toml maps them), and nothing
else is installed at the top level. In a checkout they stay top-level folders beside this
package: the package's search path then also holds the checkout's root, so the same import
names work in both.
"""

import os as _os

# OpenBLAS sizes its thread pool from the machine, not from the CPUs this process may use;
# in a container with 2 of many CPUs that oversubscription makes a small matrix product
# hundreds of times slower (0.8 s instead of 2 ms for a 25000 x 41 Gram matrix). One thread:
# on 2 cores two bought nothing (fit 4.36 s with two, 4.55 s with one; diagnose 10.6 s and
# 10.3 s, on sample_runs), and with one thread a bundle's numbers do not depend on how many
# CPUs the machine has, nor on whether ``batch`` ran the press here or on a Dask worker (the
# partial sums of a threaded product differ in their last bits). OpenBLAS reads the variable
# when it loads, so set it (unless the user has) before numpy is imported.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

_here = _os.path.dirname(_os.path.abspath(__file__))
_root = _os.path.dirname(_here)
if not _os.path.isdir(_os.path.join(_here, "pipelines")) and all(
    _os.path.exists(_os.path.join(_root, *p))
    for p in (("pyproject.toml",), ("pipelines", "__init__.py"), ("piezocli", "__init__.py"))
):
    __path__.append(_root)  # a checkout: piezopress.pipelines is <root>/pipelines

__version__ = "0.1.0"
