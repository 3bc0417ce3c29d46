"""Build of the optional native kernel (ftstab_mj/simulation/native/kernel.c, laws.c); all metadata is in pyproject.toml.

The extension is optional: when no C compiler works, setuptools warns and the install goes on
without it, and ftstab_mj runs the pure NumPy controller (and says so once).
"""

import shutil
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class BuildExt(build_ext):
    """Adds the flags the kernel relies on when the compiler understands them (gcc/clang)."""

    def build_extensions(self):
        if self.compiler.compiler_type == "unix":
            for ext in self.extensions:
                # no errno from pow (lets it be called directly); no fused multiply-add, so the
                # kernel rounds like the NumPy reference does.
                ext.extra_compile_args += ["-O2", "-fno-math-errno", "-ffp-contract=off"]
                ext.libraries += ["m", "pthread"]
        super().build_extensions()


class BuildPyWithData(build_py):
    """Copies models/ and scenarios/ into the built package (ftstab_mj/_data/), so that a wheel
    (plain `pip install .`) carries them; ftstab_mj.config.resources finds either copy."""

    def run(self):
        super().run()
        for name in ("models", "scenarios"):
            target = Path(self.build_lib) / "ftstab_mj" / "_data" / name
            shutil.rmtree(target, ignore_errors=True)
            shutil.copytree(ROOT / name, target, ignore=shutil.ignore_patterns("__pycache__"))


setup(
    ext_modules=[Extension("ftstab_mj.simulation.native._kernel",
                           [f"ftstab_mj/simulation/native/{name}.c" for name in ("kernel", "laws")],
                           depends=["ftstab_mj/simulation/native/laws.h"], optional=True)],
    cmdclass={"build_ext": BuildExt, "build_py": BuildPyWithData},
)
