"""Builds the compiled inner loops, each beside the module it serves; everything else is in
pyproject.toml."""

from Cython.Build import cythonize
from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext
from setuptools.errors import CompileError, ExecError, LinkError, PlatformError

KERNELS = ("mapping/_grid", "mapping/_changes", "localization/_match", "localization/_corners",
           "localization/_loops", "localization/_graph")

NO_COMPILER = (
    "dynslam: building its compiled kernels needs a C compiler and the Python headers, and "
    "this machine could not compile them ({error}); install them (Debian/Ubuntu: apt install "
    "build-essential python3-dev; Fedora: dnf install gcc python3-devel; macOS: "
    "xcode-select --install; Windows: Visual Studio Build Tools, C++ workload) or install a "
    "prebuilt wheel.")


class BuildKernels(build_ext):
    """build_ext that says in one sentence what is missing when nothing can compile."""

    def run(self) -> None:
        try:
            super().run()
        except (CompileError, ExecError, LinkError, PlatformError) as e:
            raise SystemExit(NO_COMPILER.format(error=f"{type(e).__name__}: {e}")) from None


setup(
    cmdclass={"build_ext": BuildKernels},
    ext_modules=cythonize(
        [Extension("dynslam_cli." + k.replace("/", "."), [f"dynslam_cli/{k}.pyx"])
         for k in KERNELS],
        compiler_directives={"language_level": 3},
    ),
)
