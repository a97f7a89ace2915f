"""Build hook; all other configuration is in pyproject.toml.

The project keeps non-Python assets in top-level folders (``schemas/``: the USD
schema plugin and Sdr shader definition; ``codegen/``: the shader runtime,
templates and examples). A source checkout and the editable install (``pip install -e .``) read them from the checkout; pyproject-only
setuptools cannot put a folder from outside the package into a wheel, so this
hook copies each of them into the built package, where the runtime looks
first (see ``mtlx2neural.usd_schema.plugin_path``). ``MANIFEST.in`` puts the
folders into the sdist, so a wheel built from the sdist has them too.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
# top-level folder -> folder inside the built package
SHIPPED_DIRS = {"schemas": "mtlx2neural/_schemas", "codegen": "mtlx2neural/_codegen"}


class BuildPyWithDataDirs(build_py):
    """build_py, then copy :data:`SHIPPED_DIRS` into the build tree (not for editable installs)."""

    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return  # the package runs from the checkout, next to the folders
        for src, dst in SHIPPED_DIRS.items():
            shutil.copytree(ROOT / src, Path(self.build_lib) / dst, dirs_exist_ok=True,
                            ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


setup(cmdclass={"build_py": BuildPyWithDataDirs})
