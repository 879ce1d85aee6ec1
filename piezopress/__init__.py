"""piezopress: open-loop force control of piezoelectric presses.

Architecture (imports go one way only, top to bottom)::

    piezocli/      command line (click): parses, calls pipelines, prints
    pipelines/     stages that read and write files: characterize, import, ...
    piezopress/acquisition/   protocols (plans, waveforms) and backends (virtual rig, DAQ)
    piezopress/analysis/      models, fits, metrics, diagnosis: pure math on numpy arrays
    piezopress/runformat.py   the Parquet run format (schema version 1)

``analysis`` never imports ``acquisition`` and neither imports ``pipelines`` or ``piezocli``.
"""

__version__ = "0.1.0"
