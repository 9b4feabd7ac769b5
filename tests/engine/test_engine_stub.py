"""The extension's stub, python/optix_e2e/_engine.pyi, against the built module: the same
functions and exception classes, each function with the same parameters in the same order and
the same defaults (from the signature pyo3 records); and optix_e2e.engine wraps every one."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import optix_e2e._engine as ext
from optix_e2e import engine

STUB = Path(__file__).resolve().parents[2] / "python" / "optix_e2e" / "_engine.pyi"


def _stub():
    tree = ast.parse(STUB.read_text(encoding="utf-8"))
    funcs = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
    classes = {n.name for n in tree.body if isinstance(n, ast.ClassDef)}
    return funcs, classes


def _stub_params(fn: ast.FunctionDef) -> list[tuple[str, object]]:
    args = fn.args.args
    defaults = [None] * (len(args) - len(fn.args.defaults)) + list(fn.args.defaults)
    out = []
    for a, d in zip(args, defaults):
        out.append((a.arg, inspect.Parameter.empty if d is None else ast.literal_eval(d)))
    return out


def test_the_stub_names_what_the_module_has():
    funcs, classes = _stub()
    public = {n for n in dir(ext) if not n.startswith("_")}
    built_funcs = {n for n in public if callable(getattr(ext, n)) and not isinstance(getattr(ext, n), type)}
    built_classes = {n for n in public if isinstance(getattr(ext, n), type)}
    assert set(funcs) == built_funcs, (sorted(set(funcs) - built_funcs), sorted(built_funcs - set(funcs)))
    assert classes == built_classes


def test_every_stub_signature_matches_the_built_function():
    funcs, _ = _stub()
    for name, fn in funcs.items():
        built = [(p.name, p.default) for p in inspect.signature(getattr(ext, name)).parameters.values()]
        assert _stub_params(fn) == built, name


def test_the_engine_module_wraps_every_function_and_names_every_argument():
    funcs, _ = _stub()
    for name in funcs:
        wrapper = getattr(engine, name)
        params = list(inspect.signature(wrapper).parameters.values())
        # the lens (or lenses, or data) positional; everything else keyword-only
        assert all(p.kind is inspect.Parameter.KEYWORD_ONLY for p in params[1:]), name
