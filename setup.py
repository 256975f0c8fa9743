"""Build step of biasgt: ship the Snakemake workflow inside the ``biasgt`` package.

The workflow files stay where a source checkout uses them (``Snakefile``, ``workflow/``, the
default ``config/config.yaml``); a built wheel also holds them under ``biasgt/workflow_files/``
with the same layout, so that ``biasgt run`` finds them (``importlib.resources``) in an installed,
non-editable package. Everything else is in ``pyproject.toml``.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
#: What the workflow needs at run time, relative to the repository root (= to workflow_files/).
WORKFLOW_FILES = ("Snakefile", "workflow", "config/config.yaml")


class BuildPyWithWorkflow(build_py):
    """``build_py`` that also copies :data:`WORKFLOW_FILES` into ``biasgt/workflow_files``."""

    def run(self) -> None:
        super().run()
        if self.editable_mode:  # an editable install runs from the checkout, which has the files
            return
        dest = Path(self.build_lib) / "biasgt" / "workflow_files"
        ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
        for name in WORKFLOW_FILES:
            src, out = ROOT / name, dest / name
            out.parent.mkdir(parents=True, exist_ok=True)
            if src.is_dir():
                shutil.copytree(src, out, ignore=ignore, dirs_exist_ok=True)
            else:
                shutil.copy2(src, out)


setup(cmdclass={"build_py": BuildPyWithWorkflow})
