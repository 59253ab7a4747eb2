"""Compiling the MPC's CasADi Functions to machine code with the system's C compiler, cached on disk.

CasADi evaluates a symbolic Function in its virtual machine; the linearisation of the horizon (~0.6
million instructions with 25 intervals) then costs ~5 ms per control step on a loaded 2-core machine,
against ~0.5 ms compiled. :func:`compile_functions` writes the C code of the Functions (CasADi's code
generator), compiles it once with ``$CC`` / ``cc`` / ``gcc`` (``-O1``: ~6 s for the model's RK4 and its
Jacobians) into a shared library named after the hash of the code, and loads it with
``casadi.external``. The cache directory is ``$SOFTPVTOL_GYM_CACHE_DIR`` (or ``$XDG_CACHE_HOME/softpvtol-gym``,
``~/.cache/softpvtol-gym``) + ``/casadi``, as the package's numba cache; a library is written under a
temporary name and renamed, so concurrent processes never load a half-written one.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from ..._cache import cache_base
from ._casadi import import_casadi

COMPILE_FLAGS = ("-O1", "-shared", "-fPIC")


def find_compiler() -> str | None:
    """The C compiler to use: ``$CC``, else ``cc`` or ``gcc`` on the PATH; None if there is none."""
    cc = os.environ.get("CC")
    if cc:
        return shutil.which(cc) or cc
    return shutil.which("cc") or shutil.which("gcc")


def cache_dir() -> Path:
    path = cache_base() / "casadi"
    try:
        path.mkdir(parents=True, exist_ok=True)
        return path
    except OSError:
        path = Path(tempfile.gettempdir()) / "softpvtol-gym-casadi"
        path.mkdir(parents=True, exist_ok=True)
        return path


def compile_functions(functions, compiler: str) -> list:
    """The CasADi Functions ``functions`` compiled to one shared library (cached by the hash of their C
    code, the compiler and its flags), loaded as ``casadi.external`` Functions of the same names.
    RuntimeError (with the compiler's message) if compiling fails."""
    ca = import_casadi()
    gen = ca.CodeGenerator("softpvtol_mpc.c", {"with_header": False})
    for fn in functions:
        gen.add(fn)
    code = gen.dump()
    key = hashlib.sha256("\0".join([code, compiler, *COMPILE_FLAGS, ca.__version__]).encode()).hexdigest()[:20]
    suffix = ".dylib" if sys.platform == "darwin" else ".so"
    directory = cache_dir()
    lib = directory / f"softpvtol_mpc_{key}{suffix}"
    if not lib.exists():
        with tempfile.TemporaryDirectory(dir=directory) as tmp:
            src = Path(tmp) / "softpvtol_mpc.c"
            src.write_text(code)
            out = Path(tmp) / lib.name
            run = subprocess.run([compiler, *COMPILE_FLAGS, "-o", str(out), str(src), "-lm"],
                                 capture_output=True, text=True)
            if run.returncode != 0 or not out.exists():
                raise RuntimeError(f"compiling the MPC's model with {compiler} failed (exit {run.returncode}): "
                                   f"{(run.stderr or run.stdout).strip()[-2000:]}")
            os.replace(out, lib)
    return [ca.external(fn.name(), str(lib)) for fn in functions]
