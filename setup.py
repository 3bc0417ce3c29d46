"""Build of the optional native kernel (ftstab_mj/native/kernel.c); all metadata is in pyproject.toml.

The extension is optional: when no C compiler works, setuptools warns and the install goes on
without it, and ftstab_mj runs the pure NumPy controller (and says so once).
"""

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext


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


setup(
    ext_modules=[Extension("ftstab_mj.native._kernel", ["ftstab_mj/native/kernel.c"], optional=True)],
    cmdclass={"build_ext": BuildExt},
)
