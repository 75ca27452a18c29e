"""Builds the optional compiled kernels (``edge/native/*.pyx``) ahead of time.

Everything else is declared in pyproject.toml. Without a C compiler, or with
RADAR_EDGE_BUILD_KERNELS=0, the package installs without kernels and the numpy reference
implementations run instead (``edge.native`` warns once at start and ``doctor`` says so).
"""

from __future__ import annotations

import glob
import os
import sys

from setuptools import setup
from setuptools.command.build_ext import build_ext


class OptionalBuildExt(build_ext):
    """build_ext that reports a failed kernel build and carries on without it."""

    def run(self) -> None:
        try:
            super().run()
        except Exception as exc:  # no compiler, missing headers
            print(f"radar-edge: compiled kernels not built ({exc}); the numpy fallback will run",
                  file=sys.stderr)

    def build_extension(self, ext) -> None:
        try:
            super().build_extension(ext)
        except Exception as exc:
            print(f"radar-edge: kernel {ext.name} not built ({exc}); the numpy fallback will run",
                  file=sys.stderr)


def _extensions() -> list:
    if os.environ.get("RADAR_EDGE_BUILD_KERNELS", "1") == "0":
        return []
    sources = sorted(glob.glob(os.path.join("edge", "native", "*.pyx")))
    if not sources:
        return []
    try:
        import numpy
        from Cython.Build import cythonize
        from setuptools import Extension
    except ImportError as exc:
        print(f"radar-edge: compiled kernels not built ({exc}); the numpy fallback will run",
              file=sys.stderr)
        return []
    exts = [
        Extension(
            "edge.native." + os.path.splitext(os.path.basename(src))[0],
            [src],
            include_dirs=[numpy.get_include()],
            define_macros=[("NPY_NO_DEPRECATED_API", "NPY_1_7_API_VERSION")],
            # no fused multiply-add (the default on arm64): the kernels round like the numpy reference
            extra_compile_args=["-O3", "-ffp-contract=off"],
        )
        for src in sources
    ]
    return cythonize(exts, language_level=3, quiet=True,
                     compiler_directives={"boundscheck": False, "wraparound": False,
                                          "cdivision": True, "initializedcheck": False})


setup(ext_modules=_extensions(), cmdclass={"build_ext": OptionalBuildExt})
