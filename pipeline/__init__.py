"""biasgt: ground-truth IMU bias from recorded data, and models that predict it.

The ``pipeline`` package holds the data model, readers, input checks, the
simulator, the integration engine, the CLI and the Snakemake glue.
"""

__version__ = "0.1.0"
