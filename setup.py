"""Builds the Python package `surfacer` with the repository's CMake project and installs build/.../python/surfacer.

    python3 -m pip install --no-index --no-build-isolation .

The extension links the client library and the in-process server, so this is a build of the C++ project (targets
surfacer_python and its type stubs only): about 15 minutes on 2 cores from nothing, seconds when the build tree is
current. The build tree is $SURFACER_BUILD_DIR when set, else build/ when scripts/setup.sh made it, else
build/python-package. Needs what scripts/setup.sh installs.
"""

import os
import re
import shutil
import subprocess
import sys
import sysconfig

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.dist import Distribution

ROOT = os.path.dirname(os.path.abspath(__file__))


def cmake_version():
    with open(os.path.join(ROOT, "CMakeLists.txt"), encoding="utf-8") as f:
        match = re.search(r"project\(surfacer VERSION ([0-9.]+)", f.read())
    if not match:
        sys.exit("setup.py: no `project(surfacer VERSION x.y.z` in CMakeLists.txt")
    return match.group(1)


class BuildWithCMake(build_py):
    """Builds the package in the CMake build tree, then copies it where setuptools makes the wheel."""

    def run(self):
        build = os.environ.get("SURFACER_BUILD_DIR")
        if not build:
            made = os.path.exists(os.path.join(ROOT, "build", "CMakeCache.txt"))
            build = os.path.join(ROOT, "build") if made else os.path.join(ROOT, "build", "python-package")
        build = os.path.abspath(build)
        if not os.path.exists(os.path.join(build, "CMakeCache.txt")):
            generator = ["-G", "Ninja"] if shutil.which("ninja") else []
            subprocess.check_call(["cmake", "-S", ROOT, "-B", build, *generator, "-DCMAKE_BUILD_TYPE=Release",
                                   "-DSURFACER_BUILD_TESTS=OFF", "-DSURFACER_BUILD_BENCH=OFF",
                                   "-DPython3_EXECUTABLE=" + sys.executable])
        subprocess.check_call(["cmake", "--build", build, "--target", "surfacer_python", "surfacer_python_stubs",
                               "-j", str(os.cpu_count() or 1)])
        source = os.path.join(build, "python", "surfacer")
        extension = "_surfacer" + sysconfig.get_config_var("EXT_SUFFIX")
        if not os.path.exists(os.path.join(source, extension)):
            sys.exit("setup.py: %s has no %s: that build tree is for another Python (its Python3_EXECUTABLE); set "
                     "SURFACER_BUILD_DIR to a new directory to build for %s" % (source, extension, sys.executable))
        target = os.path.join(self.build_lib, "surfacer")
        if os.path.exists(target):
            shutil.rmtree(target)
        shutil.copytree(source, target, ignore=shutil.ignore_patterns("__pycache__", "*.tmp"))


class BinaryDistribution(Distribution):
    """A wheel for this interpreter and platform: the package holds a compiled extension."""

    def has_ext_modules(self):
        return True


# setuptools' own files (build/lib..., surfacer.egg-info) go below build/ (ignored by git), not beside the sources.
SETUPTOOLS_DIR = os.path.join("build", "python-package", "setuptools")
os.makedirs(os.path.join(ROOT, SETUPTOOLS_DIR), exist_ok=True)
setup(version=cmake_version(), packages=["surfacer"], package_dir={"surfacer": "python/surfacer"},
      cmdclass={"build_py": BuildWithCMake}, distclass=BinaryDistribution, zip_safe=False,
      options={"build": {"build_base": SETUPTOOLS_DIR}, "egg_info": {"egg_base": SETUPTOOLS_DIR}})
