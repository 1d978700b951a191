"""Builds the compiled inner loops (dynslam_cli/kernels.pyx); everything else is in
pyproject.toml."""

from Cython.Build import cythonize
from setuptools import Extension, setup

setup(ext_modules=cythonize(
    [Extension("dynslam_cli.kernels", ["dynslam_cli/kernels.pyx"])],
    compiler_directives={"language_level": 3},
))
