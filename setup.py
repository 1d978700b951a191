"""Builds the compiled inner loops, each beside the module it serves; everything else is in
pyproject.toml."""

from Cython.Build import cythonize
from setuptools import Extension, setup

KERNELS = ("mapping/_grid", "localization/_match", "localization/_corners",
           "localization/_loops", "localization/_graph")

setup(ext_modules=cythonize(
    [Extension("dynslam_cli." + k.replace("/", "."), [f"dynslam_cli/{k}.pyx"]) for k in KERNELS],
    compiler_directives={"language_level": 3},
))
