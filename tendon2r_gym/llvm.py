"""Keeps triton's LLVM apart from Mesa's in one process, whichever comes first.

The clash: triton's ``libtriton.so`` (torch._dynamo imports triton, and SB3's Adam imports
torch._dynamo, so loading or training a PPO model loads it) links its own LLVM statically and
exports its symbols.  Mesa's software OpenGL (llvmpipe: MuJoCo's EGL and OSMesa backends on a
machine without a GPU driver) brings the system's ``libLLVM`` into the process's global symbol
scope: EGL when the first GL context is made, OSMesa as soon as ``import mujoco`` (PyOpenGL
loads libOSMesa globally).  A libtriton loaded after that binds its static initializers to
that other LLVM's functions, whose data layout differs, and the process dies with SIGSEGV in
``llvm::cl::Option::addArgument``.  A libtriton loaded before binds to its own LLVM, and Mesa
later to its own.  (``TORCHDYNAMO_DISABLE`` does not help: torch._dynamo imports triton
regardless, and the optimizer imports torch._dynamo.)

`load_triton` loads libtriton first where this package is about to bring Mesa's LLVM in
(an env made with a ``render_mode``; ``import tendon2r_gym`` with ``MUJOCO_GL=osmesa``) and
before PPOPolicy.load loads a model.  If Mesa's LLVM is already there (a GL context made by
other code), it loads libtriton with ``RTLD_DEEPBIND``, so that libtriton resolves its own
symbols first.
Without triton (an install without torch, or a system other than Linux) it does nothing and
loads nothing.
"""

from __future__ import annotations

import ctypes
import functools
import importlib.util
import os
import sys
from pathlib import Path

#: An LLVM function that libtriton's static initializers call: defined in the global symbol
#: scope once a GL library has loaded the system's libLLVM there.
LLVM_SYMBOL = "_ZN4llvm2cl6Option11addArgumentEv"


def llvm_in_global_scope() -> bool:
    """Whether a library loaded globally (Mesa's libLLVM) already defines LLVM's symbols."""
    return hasattr(ctypes.CDLL(None), LLVM_SYMBOL)


@functools.cache
def load_triton() -> str | None:
    """Loads triton's native library if triton is installed and not loaded yet (module
    docstring); returns how ("first", or "deepbind" after Mesa's LLVM), or None if it did not
    load it (no triton, already loaded, or it cannot be loaded safely here)."""
    if not sys.platform.startswith("linux"):
        return None
    spec = importlib.util.find_spec("triton")  # finds the package without importing it
    if spec is None or spec.origin is None or "triton._C.libtriton" in sys.modules:
        return None
    libs = sorted(Path(spec.origin).parent.glob("_C/libtriton*.so"))
    if not libs:
        return None
    how, mode = "first", os.RTLD_NOW | os.RTLD_LOCAL  # as Python loads an extension module
    if llvm_in_global_scope():
        deepbind = getattr(os, "RTLD_DEEPBIND", 0)  # glibc only
        if not deepbind:
            return None
        how, mode = "deepbind", mode | deepbind
    try:
        # Python's later import of triton._C.libtriton gets this same, initialized library.
        ctypes.CDLL(str(libs[0]), mode=mode)
    except OSError:  # a broken triton install: importing triton will report it
        return None
    return how


# With OSMesa, importing mujoco already brings Mesa's LLVM in; the package's __init__ imports
# this module before any module that imports mujoco.
if os.environ.get("MUJOCO_GL", "").strip().lower() == "osmesa":
    load_triton()
