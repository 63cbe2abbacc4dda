"""The package's layers: a module may import its own layer and the layers below it, never one above."""

import ast
import pathlib

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "match_jax"
# Lowest first. Modules directly under match_jax/ (XLA flags, the compile cache, CLI helpers) are the base.
LAYERS = ("envs", "rl", "training", "experiments", "transfer")


def layer_of(module: str) -> int:
    """0 for the base modules, 1 + the index in LAYERS for a module in a layer's subpackage."""
    parts = module.split(".")
    assert parts[0] == "match_jax", module
    if len(parts) > 1 and parts[1] in LAYERS:
        return 1 + LAYERS.index(parts[1])
    return 0


def imported_modules(source: str, module: str) -> set[str]:
    """The match_jax modules `source` imports (top-level and inside functions), as dotted names."""
    found = set()
    package = module.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split(".")[0] == "match_jax"}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                name = f"{base}.{node.module}" if node.module else base
            else:
                name = node.module or ""
            if name.split(".")[0] != "match_jax":
                continue
            # `from match_jax.x import y`: y may be a module of a layer (from match_jax import rl)
            found |= {f"{name}.{a.name}" if name == "match_jax" else name for a in node.names}
    return found


def violations(source: str, module: str) -> list[str]:
    own = layer_of(module)
    return sorted(f"{module} (layer {own}) imports {imported} (layer {layer_of(imported)})"
                  for imported in imported_modules(source, module) if layer_of(imported) > own)


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts[-1] = "_init_"  # a package's own __init__ sits in the package's layer
        yield ".".join(parts), path


def test_no_module_imports_a_higher_layer():
    found = [v for module, path in _modules() for v in violations(path.read_text(), module)]
    assert not found, "\n".join(found)


def test_every_subpackage_is_a_known_layer():
    subpackages = {p.parent.relative_to(PACKAGE).parts[0] for p in PACKAGE.rglob("__init__.py") if p.parent != PACKAGE}
    assert subpackages == set(LAYERS)


@pytest.mark.parametrize("source, module, bad", [
    ("from match_jax.rl.ppo import PPOConfig", "match_jax.envs.fpih", True),
    ("def f():\n    from match_jax.transfer import export\n", "match_jax.training.runs", True),
    ("from match_jax import experiments", "match_jax.rl.losses", True),
    ("from . import pipeline", "match_jax.training.runs", False),
    ("from ..experiments import plots", "match_jax.training.runs", True),
    ("from match_jax.envs import sim", "match_jax.rl.ppo", False),
    ("from match_jax import compile_cache", "match_jax.envs.sim", False),
])
def test_the_check_catches_an_upward_import(source, module, bad):
    assert bool(violations(source, module)) is bad
