"""Packaging metadata agrees with itself: the version in pyproject.toml, jaxsat.__version__,
the installed distribution and CHANGELOG.md; the license named and shipped. (.ci/wheel builds
and installs the wheel itself.)"""

from __future__ import annotations

import importlib.metadata
import pathlib

import pytest

import jaxsat

ROOT = pathlib.Path(__file__).resolve().parent.parent

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    tomllib = pytest.importorskip("tomli")


@pytest.fixture(scope="module")
def project():
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]


def test_version_is_pyprojects(project):
    assert jaxsat.__version__ == project["version"]


def test_installed_metadata_has_the_same_version():
    try:
        installed = importlib.metadata.version("jaxsat")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("jaxsat is imported from a source tree without being installed")
    assert installed == jaxsat.__version__


def test_changelog_has_an_entry_for_the_version():
    changelog = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    assert "## [Unreleased]" in changelog
    assert f"## [{jaxsat.__version__}] - " in changelog


def test_license_is_named_and_shipped(project):
    assert project["license"] == "Apache-2.0"
    assert project["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "END OF TERMS AND CONDITIONS" in text
    assert "Copyright 2026 the jaxsat authors" in text
