"""Test configuration: import piezopress first so that its thread settings apply before numpy loads."""

import piezopress  # noqa: F401  (sets OPENBLAS_NUM_THREADS before numpy is imported)
