"""The package's seams: every module stands on the others' public names only."""

from __future__ import annotations

import ast
import pathlib

import jaxsat

PACKAGE = pathlib.Path(jaxsat.__file__).parent


def _crossing_private_names(path: pathlib.Path) -> list[str]:
    """Underscore names that `path` takes from another jaxsat module: imported by name, or
    read as an attribute of an imported module (`from jaxsat import _shapes as shapes`)."""
    tree = ast.parse(path.read_text())
    modules, found = {}, []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("jaxsat"):
            for alias in node.names:
                if node.module == "jaxsat":
                    modules[alias.asname or alias.name] = alias.name
                elif alias.name.startswith("_"):
                    found.append(f"{node.module}.{alias.name}")
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in modules and node.attr.startswith("_")):
            found.append(f"{modules[node.value.id]}.{node.attr}")
    return found


def test_no_module_imports_another_modules_private_names():
    crossing = {path.name: names for path in sorted(PACKAGE.glob("*.py"))
                if path.name != "__init__.py" and (names := _crossing_private_names(path))}
    assert crossing == {}


def test_the_checker_sees_both_kinds_of_crossing(tmp_path):
    """The check above can fail: it finds a private import and a private attribute."""
    source = tmp_path / "module.py"
    source.write_text("from jaxsat._shapes import _pad_rows\nfrom jaxsat import _shapes as s\n"
                      "x = s._padded_fields\ny = s.stack\n")
    assert _crossing_private_names(source) == ["jaxsat._shapes._pad_rows", "_shapes._padded_fields"]


def _builtin_sum_calls(path: pathlib.Path) -> list[int]:
    """Lines of `path` that call Python's built-in `sum`."""
    return [node.lineno for node in ast.walk(ast.parse(path.read_text()))
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
            and node.func.id == "sum"]


def test_sums_of_terms_go_through_the_kernel_layer():
    """The package adds terms with `_kernels.total` (or `vsum`, `vdot`), never Python's
    `sum`, which starts from the integer 0 and adds through jnp's jitted operator: a nested
    jit per term that JAX traces again under vmap and grad (kernel rule 6)."""
    calls = {path.name: lines for path in sorted(PACKAGE.glob("*.py"))
             if (lines := _builtin_sum_calls(path))}
    assert calls == {}


def test_the_sum_checker_sees_a_call_of_the_builtin(tmp_path):
    """The check above can fail: it finds `sum(...)`, not a method or jnp's function."""
    source = tmp_path / "module.py"
    source.write_text("import jax.numpy as jnp\nx = jnp.sum(y)\nz = y.sum()\n"
                      "w = sum(v * v for v in y)\n")
    assert _builtin_sum_calls(source) == [4]


def test_public_api_is_listed_once_in_all():
    names = [name for name in dir(jaxsat) if not name.startswith("_")]
    assert len(jaxsat.__all__) == len(set(jaxsat.__all__))
    assert set(jaxsat.__all__) <= set(names)
    modules = {"jaxsat"} | {path.stem for path in PACKAGE.glob("_*.py")}
    assert set(names) - set(jaxsat.__all__) <= modules | {"annotations"}


def test_benchmarks_stay_small():
    """The benchmark scripts stay at most 2,000 lines and their README at most 2,500 words
    (counted as `wc -w` does), so that results and how to get them stay easy to find."""
    benchmarks = pathlib.Path(__file__).resolve().parents[1] / "benchmarks"
    lines = sum(len(path.read_text().splitlines()) for path in benchmarks.glob("*.py"))
    words = len((benchmarks / "README.md").read_text().split())
    assert lines <= 2000, f"benchmarks/*.py: {lines} lines"
    assert words <= 2500, f"benchmarks/README.md: {words} words"
