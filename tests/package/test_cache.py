"""The numba cache lives outside the package, in a directory per version of the package's source."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

import softpvtol_gym
from softpvtol_gym import _cache


def test_cache_dir_is_named_after_the_source_and_is_used():
    from numba.core import config

    path = Path(softpvtol_gym.NUMBA_CACHE_DIR)
    assert config.CACHE_DIR == str(path)
    assert path.name == f"numba-{_cache.source_digest()}"
    assert not path.is_relative_to(_cache.PACKAGE_DIR)


@pytest.mark.parametrize("later", ["", "user_cache"])
def test_a_numba_variable_set_after_the_import_keeps_the_cache_directory(tmp_path, later):
    """numba reloads its configuration at the next compile when a NUMBA_* variable changed; the package's cache
    directory stays unless the user then sets NUMBA_CACHE_DIR, which is theirs to choose."""
    user_dir = str(tmp_path / later) if later else ""
    code = ("import os, numba, softpvtol_gym\n"
            "from numba.core import config\n"
            "os.environ['NUMBA_OPT'] = '2'\n"
            f"if {user_dir!r}: os.environ['NUMBA_CACHE_DIR'] = {user_dir!r}\n"
            "assert numba.njit(lambda x: x + 1)(1) == 2\n"
            "print(config.CACHE_DIR); print(softpvtol_gym.NUMBA_CACHE_DIR)\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    numba_dir, package_dir = out.stdout.split()
    assert numba_dir == (user_dir or package_dir)


def test_source_digest_changes_with_any_source_file(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "b.py").write_text("y = 2\n")
    first = _cache.source_digest(pkg)
    assert _cache.source_digest(pkg) == first
    (pkg / "sub" / "b.py").write_text("y = 3\n")
    assert _cache.source_digest(pkg) != first


def test_unwritable_cache_base_falls_back_to_a_temporary_directory(tmp_path):
    base = tmp_path / "read_only"
    base.mkdir()
    base.chmod(0o500)
    env = dict(os.environ, SOFTPVTOL_GYM_CACHE_DIR=str(base))
    code = "import softpvtol_gym, tempfile; print(softpvtol_gym.NUMBA_CACHE_DIR); print(tempfile.gettempdir())"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    cache, tmp = out.stdout.split()
    if os.geteuid() != 0:  # root may write anywhere
        assert cache.startswith(tmp)
    assert Path(cache).name.startswith("numba-")
