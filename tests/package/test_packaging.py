"""Packaging habits: the version in one place (softpvtol_gym/_version.py, read by pyproject.toml and repeated by
CITATION.cff), the license named the same in LICENSE, pyproject.toml and CITATION.cff."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import pytest
import yaml

import softpvtol_gym

ROOT = Path(__file__).resolve().parents[2]


def _pyproject() -> dict:
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_version_is_read_from_the_package():
    project = _pyproject()["project"]
    assert "version" not in project and "version" in project["dynamic"]
    attr = _pyproject()["tool"]["setuptools"]["dynamic"]["version"]["attr"]
    assert attr == "softpvtol_gym._version.__version__"
    from softpvtol_gym._version import __version__

    assert softpvtol_gym.__version__ == __version__


def test_installed_metadata_has_the_package_version():
    try:
        installed = importlib.metadata.version("softpvtol-gym")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("softpvtol-gym is not installed (run from a checkout without pip install)")
    assert installed == softpvtol_gym.__version__


def test_citation_cff_names_this_version_and_the_paper():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    # YAML would read 0.1 or 1.0 as floats: the version must stay a string equal to the package's
    assert cff["version"] == softpvtol_gym.__version__
    assert cff["license"] == "MIT" and cff["authors"] and cff["message"]
    paper = cff["references"][0]
    assert paper["title"] == "The Soft-PVTOL: modeling and control"
    assert [a["family-names"] for a in paper["authors"]] == ["Flores", "Spong"]


def test_one_license_everywhere():
    assert (ROOT / "LICENSE").read_text().startswith("MIT License\n")
    project = _pyproject()["project"]
    assert project["license"] == "MIT" and project["license-files"] == ["LICENSE"]


def _names(requirements: list[str]) -> set[str]:
    """Distribution names (and self-references with their extras) of requirement strings."""
    import re

    return {re.split(r"[<>=!~;\s]", r, maxsplit=1)[0] for r in requirements}


def test_plain_install_is_the_env_and_extras_add_the_rest():
    """`pip install softpvtol-gym`: gymnasium, numpy, numba (tests/package/test_extras.py runs it without the rest);
    torch and stable-baselines3 come with 'train', pygame with 'render', and 'test' installs every extra."""
    project = _pyproject()["project"]
    assert _names(project["dependencies"]) == {"gymnasium", "numpy", "numba"}
    extras = project["optional-dependencies"]
    assert _names(extras["train"]) == {"torch", "stable-baselines3"}
    assert _names(extras["render"]) == {"pygame"}
    assert "softpvtol-gym[train,render]" in extras["baselines"]
    everything = {e for e in extras if e not in ("test", "dev")}
    self_ref = next(r for r in extras["test"] if r.startswith("softpvtol-gym["))
    covered = set(self_ref[len("softpvtol-gym["):-1].split(","))
    covered |= {"train", "render"}  # through baselines
    assert covered == everything, everything - covered
    assert any(r.startswith("ruff==") for r in extras["test"]), "CI's linter is pinned to one version"
