"""A biasgt plugin: one entry of each registry, found through its entry points (pyproject.toml).

The entries name their implementations as ``"module:attribute"``: importing this module (which every
biasgt command does when it first reads a registry) imports neither torch nor the implementations.
"""

from pipeline.io.registry import Reader
from pipeline.types import Verdict
from training.networks import Network, Objective
from training.references import ReferenceRow
from validation.rules import Rule

READER = Reader("demo_ms_g", "a demo IMU log in ms and g", "a demo IMU log (t_ms, gyro rad/s, acc in g)",
                load="biasgt_demo_plugin.reader:load", detect="biasgt_demo_plugin.reader:detect", before="csv")
NETWORK = Network("demo_linear", "Demo linear", Objective.REGRESSION, "a linear regression of the window (demo)",
                  "#17becf", "biasgt_demo_plugin.net:DemoOptions", "biasgt_demo_plugin.net:DemoNet",
                  {"tiny": {"width": 4}}, default=False)
ROW = ReferenceRow("demo_half_truth", "Half the GT bias (demo)", "half the recovered bias (demo)",
                   "biasgt_demo_plugin.row:row", needs=("bias_mean",), default=False)
RULE = Rule("DEMO_SHORT_RECORDING", Verdict.WARN, "a recording shorter than a minute (demo)",
            "biasgt_demo_plugin.rule:check", "record for a minute or more (demo)")
