"""The stack's import rules (docs/architecture.md), checked by import-linter's contracts in
pyproject.toml: every layer imports only layers below it, and no package's modules import each
other in a loop."""

import pkgutil
import tomllib
from pathlib import Path

import pytest

import stillcap

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "pyproject.toml"


def _contracts() -> dict:
    return {c["id"]: c for c in tomllib.loads(CONFIG.read_text())["tool"]["importlinter"]["contracts"]}


def test_import_rules_hold(monkeypatch):
    """lint-imports passes (it names the offending import when a layer imports upwards)."""
    from importlinter.cli import lint_imports

    monkeypatch.chdir(ROOT)
    assert lint_imports(config_filename=str(CONFIG), no_cache=True, no_logo=True) == 0


def test_every_package_is_in_a_layer():
    """A new top-level package or module cannot escape the layers contract by not being named."""
    layers = _contracts()["stack"]["layers"]
    named = {name.strip() for layer in layers for name in layer.split("|")}
    children = {m.name for m in pkgutil.iter_modules(stillcap.__path__)} - {"__main__"}
    assert children - named == set(), "add these to a layer of the stack in pyproject.toml"
    assert named - children == set(), "these layers name packages that do not exist"


@pytest.mark.parametrize("importer, imported", [("stillcap.pipelines", "stillcap.studio"),
                                                ("stillcap.detect", "stillcap.geometry.triangulate"),
                                                ("stillcap.camera", "stillcap.io"),
                                                ("stillcap.files", "stillcap.camera")])
def test_no_chain(importer, imported):
    """What the stack forbids is absent, directly or through other modules: the pipelines never
    see the studio, detection does not triangulate, cameras know no file formats, the file
    helpers import nothing of stillcap."""
    import grimp

    graph = grimp.build_graph("stillcap", cache_dir=None)
    assert not graph.chain_exists(importer=importer, imported=imported, as_packages=True), \
        graph.find_shortest_chain(importer=importer, imported=imported)
