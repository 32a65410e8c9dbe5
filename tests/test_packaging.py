"""The package as users get it: the built wheel and sdist, the installed metadata, one version
source, and the citation record."""

from __future__ import annotations

import importlib.metadata
import re
import shutil
import subprocess
import sys
import tarfile
import tomllib
import zipfile
from email.message import Message
from email.parser import Parser
from pathlib import Path

import pytest
import yaml

import excavator_surrogate
from excavator_surrogate.cli import main

ROOT = Path(__file__).resolve().parents[1]
DIST = "excavator-surrogate"
LICENSE_ID = "Apache-2.0"
URL_NAMES = {"Homepage", "Documentation", "Repository", "Issues", "Changelog"}


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def _check_metadata(md: Message, where: str) -> None:
    """The PEP 639 license, the classifiers and the project URLs of one METADATA/PKG-INFO."""
    assert md["License-Expression"] == LICENSE_ID, where
    assert "LICENSE" in (md.get_all("License-File") or []), where
    classifiers = md.get_all("Classifier") or []
    assert "Typing :: Typed" in classifiers, where
    assert any(c.startswith("Programming Language :: Python :: 3.1") for c in classifiers), where
    # PEP 639: no license classifier next to a license expression.
    assert not [c for c in classifiers if c.startswith("License ::")], where
    urls = {u.split(",")[0] for u in md.get_all("Project-URL") or []}
    assert urls >= URL_NAMES, where
    assert md["Version"] == excavator_surrogate.__version__, where


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The wheel and sdist, built offline from a copy of the tree (no build/ or egg-info here)."""
    tmp = tmp_path_factory.mktemp("pkg")
    src = tmp / "src-tree"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, src / name)
    shutil.copytree(
        ROOT / "src", src / "src", ignore=shutil.ignore_patterns("__pycache__", "*.egg-info")
    )
    out = tmp / "dist"
    out.mkdir()
    # What `pip wheel --no-build-isolation` and `python -m build -n` call: the PEP 517 hooks.
    for hook in ("build_sdist", "build_wheel"):
        code = f"import sys, setuptools.build_meta as b; b.{hook}(sys.argv[1])"
        res = subprocess.run(
            [sys.executable, "-c", code, str(out)], cwd=src, capture_output=True, text=True
        )
        assert res.returncode == 0, res.stderr[-3000:]
    (wheel,) = out.glob("*.whl")
    (sdist,) = out.glob("*.tar.gz")
    return wheel, sdist


def test_wheel_ships_license_py_typed_and_metadata(built: tuple[Path, Path]) -> None:
    wheel, _ = built
    version = excavator_surrogate.__version__
    assert wheel.name.startswith(f"excavator_surrogate-{version}-py3-none-any")
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        info = f"excavator_surrogate-{version}.dist-info"
        assert f"{info}/licenses/LICENSE" in names
        assert "excavator_surrogate/py.typed" in names
        assert "excavator_surrogate/presets/quick-hydraulic.toml" in names
        license_text = z.read(f"{info}/licenses/LICENSE").decode()
        md = Parser().parsestr(z.read(f"{info}/METADATA").decode())
    assert license_text == (ROOT / "LICENSE").read_text()
    _check_metadata(md, "wheel METADATA")


def test_sdist_ships_license(built: tuple[Path, Path]) -> None:
    _, sdist = built
    top = f"excavator_surrogate-{excavator_surrogate.__version__}"
    with tarfile.open(sdist) as t:
        names = set(t.getnames())
        assert f"{top}/LICENSE" in names
        assert f"{top}/src/excavator_surrogate/py.typed" in names
        md = Parser().parsestr(t.extractfile(f"{top}/PKG-INFO").read().decode())  # type: ignore[union-attr]
    _check_metadata(md, "sdist PKG-INFO")


def test_license_is_the_apache_text() -> None:
    text = (ROOT / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "END OF TERMS AND CONDITIONS" in text
    assert _pyproject()["project"]["license"] == LICENSE_ID


def test_installed_metadata() -> None:
    """What pip shows for the installed package (reinstall after editing pyproject.toml)."""
    _check_metadata(importlib.metadata.metadata(DIST), "installed metadata")  # type: ignore[arg-type]


def test_one_version_source(capsys: pytest.CaptureFixture[str]) -> None:
    project = _pyproject()["project"]
    assert "version" not in project and "version" in project["dynamic"]
    version = excavator_surrogate.__version__
    assert importlib.metadata.version(DIST) == version
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.split() == ["exsur", version]
    changelog = (ROOT / "CHANGELOG.md").read_text()
    assert "## [Unreleased]" in changelog and f"## [{version}] - " in changelog


def test_changelog_has_each_section_once_per_release() -> None:
    """Keep a Changelog: within a release, one ``### Added``, one ``### Changed``, ..."""
    changelog = (ROOT / "CHANGELOG.md").read_text()
    releases = re.split(r"(?m)^## ", changelog)[1:]
    assert releases
    for release in releases:
        heads = re.findall(r"(?m)^### (.+)$", release)
        assert len(heads) == len(set(heads)), f"{release.splitlines()[0]}: sections {heads}"


def test_citation_cff() -> None:
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    # The keys CFF 1.2.0 requires, at the top and in the paper's reference.
    assert cff["cff-version"] == "1.2.0"
    assert {"message", "title", "authors"} <= set(cff)
    assert cff["version"] == excavator_surrogate.__version__
    assert cff["license"] == LICENSE_ID
    paper = cff["preferred-citation"]
    assert {"type", "title", "authors"} <= set(paper)
    assert "System-Level Surrogate for Hydraulic Excavators" in " ".join(paper["title"].split())
    for person in [*cff["authors"], *paper["authors"]]:
        assert person.get("family-names") or person.get("name"), person
