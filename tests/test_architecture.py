"""The layering of docs/architecture.md, enforced on the source (an AST walk, so imports
inside functions count): a module imports only from its own subpackage, the foundations and
the layers below; no circle among a subpackage's modules, nor among the Rust engine's files;
nothing imports the CLI; the Rust extension is imported only by the engine's door,
optix_e2e.engine; files are written only through optix_e2e.io."""

from __future__ import annotations

import ast
import re
from functools import cache
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "optix_e2e"
CRATE = Path(__file__).resolve().parents[1] / "crates" / "psf-engine" / "src"

#: Each subpackage or top-level module and its layer (docs/architecture.md); a module may import
#: what sits on a lower layer, never a sibling of its own layer nor anything above.
LAYER = {
    "_engine": 0,
    "errors": 0,
    "device": 1,
    "precision": 1,
    "engine": 2,
    "io": 1,
    "color": 2,
    "parallel": 2,
    "torchfile": 2,
    "plotting": 2,
    "__version__": 2,
    "lens": 3,
    "sensor": 3,
    "scenes": 3,
    "metrics": 3,
    "isp": 4,
    "lens_design": 4,
    "accuracy": 5,
    "dataset": 6,
    "surrogate": 7,
    "optics": 8,
    "camera": 9,
    "tasks": 10,
    "camera_design": 11,
    "cli": 12,
    "__main__": 13,
}


def _imports() -> list[tuple[str, str, int]]:
    """(importing module, imported optix_e2e module, line) for every import in the package."""
    found = []
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE).with_suffix("")
        parts = list(rel.parts)
        is_init = parts[-1] == "__init__"
        if is_init:
            parts = parts[:-1]
        module = ".".join(parts)
        package = parts if is_init else parts[:-1]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package[: len(package) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                elif (node.module or "").startswith("optix_e2e"):
                    target = node.module[len("optix_e2e") :].lstrip(".")
                else:
                    continue
                found.extend((module, f"{target}.{a.name}" if target else a.name, node.lineno) for a in node.names)
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("optix_e2e."):
                        found.append((module, a.name[len("optix_e2e.") :], node.lineno))
    return found


def _top(name: str) -> str:
    return name.split(".")[0]


def test_every_subpackage_has_a_layer():
    tops = {
        p.stem if p.is_file() else p.name
        for p in PACKAGE.iterdir()
        if (p.suffix == ".py" or (p.is_dir() and (p / "__init__.py").exists())) and p.name != "__init__.py"
    }
    assert tops - {"_engine"} <= set(LAYER), f"no layer for {sorted(tops - set(LAYER))}: add it to docs/architecture.md"


def test_no_module_imports_upwards_or_sideways():
    bad = []
    for module, target, line in _imports():
        a, b = _top(module), _top(target)
        if not b or a == b or b == "_engine" or b not in LAYER:
            continue
        if LAYER[b] >= LAYER[a]:
            bad.append(f"{module}:{line} imports {target} (layer {LAYER[a]} -> {LAYER[b]})")
    assert not bad, "imports against docs/architecture.md:\n" + "\n".join(sorted(bad))


def _circles(graph: dict[str, dict[str, str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan): the circles."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out = []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            at = stack.index(v)
            if len(stack) - at > 1:
                out.append(sorted(stack[at:]))
            del stack[at:]

    for v in list(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def _describe(circles: list[list[str]], graph: dict[str, dict[str, str]]) -> str:
    return "\n".join(f"{a} -> {b} ({graph[a][b]})" for c in circles for a in c for b in c if b in graph.get(a, {}))


def _python_graph() -> dict[str, dict[str, str]]:
    """Module -> the modules of its own subpackage it imports (-> where), function-local imports included."""
    modules = set()
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        modules.add(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    graph: dict[str, dict[str, str]] = {}
    for module, target, line in _imports():
        while target and target not in modules:  # `from .a import name`: the module a
            target = target.rpartition(".")[0]
        if target != module and _top(target) == _top(module):
            graph.setdefault(module, {}).setdefault(target, f"line {line}")
    return graph


def test_no_circle_among_a_subpackages_modules():
    """Within a subpackage the modules import one way: a circle (one import of it inside a
    function is enough) means the two files are one idea, or a shared piece belongs below both."""
    graph = _python_graph()
    assert "dataset.shards" in graph["dataset.generate"]  # the walk sees the package's imports
    circles = _circles(graph)
    assert not circles, "import circles:\n" + _describe(circles, graph)


@cache
def _rust_code(path: Path) -> str:
    """A Rust file without comments, string and char literals and #[cfg(test)] modules (a
    unit test may use any module, as tests/ does)."""
    literal = r"""//[^\n]*|/\*.*?\*/|(?<!\w)b?r(#*)".*?"\1|"(?:\\.|[^"\\])*"|'(?:\\.[^']*|[^\\'])'"""
    text = re.sub(literal, " ", path.read_text(encoding="utf-8"), flags=re.S)
    while m := re.search(r"#\[cfg\(test\)\]\s*(?:#\[[^\]]*\]\s*)*(?:pub\s+)?mod\s+\w+\s*([;{])", text):
        end, depth = m.end(), int(m[1] == "{")
        while depth:
            depth += {"{": 1, "}": -1}.get(text[end], 0)
            end += 1
        text = text[: m.start()] + text[end:]
    return text


def _rust_file(module: list[str]) -> Path | None:
    if not module:
        return CRATE / "lib.rs"
    found = [p for p in (CRATE.joinpath(*module).with_suffix(".rs"), CRATE.joinpath(*module, "mod.rs")) if p.is_file()]
    return found[0] if found else None


def _rust_module(path: Path) -> list[str]:
    parts = list(path.relative_to(CRATE).with_suffix("").parts)
    return [] if parts == ["lib"] else parts[:-1] if parts[-1] == "mod" else parts


def _use_paths(tree: str) -> list[list[str]]:
    """``a::{b, c::{self, d}}`` -> a::b, a::c, a::c::d."""
    if tree.startswith("{"):
        parts, depth, cur = [], 0, ""
        for ch in tree[1:-1] + ",":
            if ch == "," and not depth:
                parts, cur = parts + [cur], ""
            else:
                depth, cur = depth + (ch == "{") - (ch == "}"), cur + ch
        return [p for part in parts if part for p in _use_paths(part)]
    head, sep, rest = tree.partition("::")
    if not sep:
        return [[]] if head in ("self", "*") else [[head]]
    return [[head] + p for p in _use_paths(rest)]


def _uses(code: str, public: bool = False) -> list[list[str]]:
    found = []
    for m in re.finditer(r"\b(pub\s*(?:\([^)]*\))?\s*)?use\s+([^;]+);", code):
        if m[1] or not public:
            found += _use_paths(re.sub(r"\s+as\s+\w+|\s+", "", m[2]))
    return found


def _absolute(path: list[str], module: list[str], children: set[str]) -> list[str] | None:
    """A path written in ``module`` from the crate's root; None for other crates."""
    if path[0] == "crate":
        return path[1:]
    if path[0] == "self":
        return module + path[1:]
    if path[0] == "super":
        base = module
        while path and path[0] == "super":
            base, path = base[:-1], path[1:]
        return base + path
    return module + path if path[0] in children else None


def _defining_file(path: list[str], hops: int = 0) -> Path:
    """The file that defines what ``path`` names, through ``pub use`` re-exports."""
    module: list[str] = []
    for i, name in enumerate(path):
        if _rust_file(module + [name]) is None:
            code = _rust_code(_rust_file(module))
            children = set(re.findall(r"\bmod\s+(\w+)\s*;", code))
            for p in _uses(code, public=True):
                if p and p[-1] == name and hops < 8:
                    again = _absolute(p, module, children)
                    if again is not None and again != module + [name]:
                        return _defining_file(again + path[i + 1 :], hops + 1)
            break
        module.append(name)
    return _rust_file(module)


def _rust_graph() -> dict[str, dict[str, str]]:
    """File -> the files whose items it uses (-> the first path), from its ``use`` trees and
    the ``crate::``/``super::``/child-module paths in its code. A module's use of its
    parent's items (psf/fast.rs of psf/mod.rs) is left out: a child is part of its parent and
    sees its private items; the parent's use of its children counts."""
    graph: dict[str, dict[str, str]] = {}
    for path in sorted(CRATE.rglob("*.rs")):
        module, code = _rust_module(path), _rust_code(path)
        children = set(re.findall(r"\bmod\s+(\w+)\s*;", code))
        body = re.sub(r"\buse\s+[^;]+;", " ", code)
        paths = _uses(code) + [m[0].split("::") for m in re.finditer(r"(?<![\w:])\w+(?:::\w+)+", body)]
        for p in paths:
            a = _absolute(p, module, children) if p else None
            if a is None:
                continue
            target = _defining_file(a)
            if target is None or target == path or _rust_module(target) == module[: len(_rust_module(target))]:
                continue
            here = graph.setdefault(path.relative_to(CRATE).as_posix(), {})
            here.setdefault(target.relative_to(CRATE).as_posix(), "::".join(p))
    return graph


def test_no_circle_among_the_engines_modules():
    """crates/psf-engine/src, file by file: the modules use each other one way (a shared
    type or helper sits in the lower file; the higher one may re-export it)."""
    graph = _rust_graph()
    assert "kernel.rs" in graph["trace.rs"] and "psf/traced.rs" in graph["psf/fast.rs"]  # the parser sees uses
    circles = _circles(graph)
    assert not circles, "circles among the engine's modules:\n" + _describe(circles, graph)


def test_nothing_imports_the_cli():
    bad = [f"{m}:{line}" for m, t, line in _imports() if _top(t) == "cli" and _top(m) not in ("cli", "__main__")]
    assert not bad, bad


def test_the_extension_is_imported_only_through_the_engine_door():
    importers = {m for m, t, _ in _imports() if "_engine" in t.split(".")}
    assert importers == {"engine"}, f"import the engine through optix_e2e.engine, not _engine: {sorted(importers)}"


#: modules that write files themselves, and why (every other write goes through optix_e2e.io)
OWN_WRITERS = {
    "io.py": "the one place files are written (atomic text, JSON, CSV, arrays, figures, images, checkpoints)",
    "dataset/layout.py": "a dataset's shard arrays by direct I/O (O_DIRECT), gigabytes that bypass the page cache",
}
_WRITE_METHODS = {"write_text", "write_bytes", "savefig", "imwrite", "savez", "savez_compressed"}


def _writes(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, what) for every call in ``tree`` that writes a file by itself: open() with a mode
    that writes, Path.write_text/write_bytes, savefig, imwrite, json.dump, torch.save, np.save."""
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Name) and f.id == "open":
            mode = (
                node.args[1] if len(node.args) > 1 else next((k.value for k in node.keywords if k.arg == "mode"), None)
            )
            if isinstance(mode, ast.Constant) and isinstance(mode.value, str) and set(mode.value) & set("wax+"):
                found.append((node.lineno, f"open(..., {mode.value!r})"))
        elif isinstance(f, ast.Attribute):
            owner = f.value.id if isinstance(f.value, ast.Name) else ""
            if f.attr in _WRITE_METHODS or (f.attr == "dump" and owner == "json"):
                found.append((node.lineno, f"{owner or '...'}.{f.attr}"))
            elif f.attr == "save" and owner in ("torch", "np", "numpy"):
                found.append((node.lineno, f"{owner}.save"))
    return found


def test_files_are_written_through_io():
    """Every file the package writes goes through optix_e2e.io (whole or absent: a temporary
    file, fsync, a rename; strict JSON), but for the writers named in OWN_WRITERS."""
    bad = []
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE).as_posix()
        if rel in OWN_WRITERS:
            continue
        bad += [f"{rel}:{line} {what}" for line, what in _writes(ast.parse(path.read_text(encoding="utf-8")))]
    assert not bad, "write through optix_e2e.io:\n" + "\n".join(sorted(bad))
    # the check finds each kind of write
    probe = ast.parse(
        "open(p, 'w')\nopen(p, mode='ab')\np.write_text(t)\nfig.savefig(p)\njson.dump(o, f)\ntorch.save(o, p)\n"
        "np.save(p, a)\nopen(p)\nopen(p, 'rb')\njson.dumps(o)\nlens.save(p)"
    )
    assert [line for line, _ in _writes(probe)] == [1, 2, 3, 4, 5, 6, 7]


def test_the_package_raises_its_own_errors():
    """docs/architecture.md, "Errors": the package raises ``errors.InputError`` / ``RunError`` (or a
    named subclass), never a bare ValueError/RuntimeError, so the CLI can tell a user's error
    (one line) from a bug (a traceback)."""
    bad = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Raise) and node.exc is not None:
                exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
                if isinstance(exc, ast.Name) and exc.id in ("ValueError", "RuntimeError", "Exception"):
                    bad.append(f"{path.relative_to(PACKAGE)}:{node.lineno} raises {exc.id}")
            if isinstance(node, ast.ClassDef) and node.name.endswith("Error") and path.name != "errors.py":
                bases = {b.id for b in node.bases if isinstance(b, ast.Name)}
                if bases and bases <= {"ValueError", "RuntimeError", "Exception"}:
                    bad.append(f"{path.relative_to(PACKAGE)}:{node.lineno} {node.name} derives from {sorted(bases)}")
    assert not bad, "\n".join(sorted(bad))


def test_named_errors_share_one_base():
    from optix_e2e.dataset.layout import DatasetError
    from optix_e2e.errors import InputError, OptixError, RunError
    from optix_e2e.lens.glass import GlassError
    from optix_e2e.lens.prescription import PrescriptionError
    from optix_e2e.lens.zemax.common import ZemaxError
    from optix_e2e.metrics.lpips import LPIPSWeightsError
    from optix_e2e.parallel import TrainingDiverged
    from optix_e2e.surrogate.checkpoint import SurrogateFileError

    for cls in (DatasetError, GlassError, PrescriptionError, ZemaxError, SurrogateFileError):
        assert issubclass(cls, InputError) and issubclass(cls, ValueError), cls
    for cls in (LPIPSWeightsError, TrainingDiverged):
        assert issubclass(cls, RunError) and issubclass(cls, RuntimeError), cls
    assert issubclass(InputError, OptixError) and issubclass(RunError, OptixError)


def test_cli_prints_package_errors_in_one_line_and_lets_bugs_show():
    import click
    import pytest
    from click.testing import CliRunner

    from optix_e2e.cli._common import friendly_errors
    from optix_e2e.engine import ArgumentError, EngineError, predicted_psf_seconds
    from optix_e2e.errors import InputError

    def command(exc):
        @click.command()
        @friendly_errors
        def cmd():
            raise exc

        return cmd

    for exc, shown in (
        (InputError("lens.json: surface 3: radius must be finite"), "Error: lens.json: surface 3"),
        (FileNotFoundError(2, "No such file or directory", "x.zmx"), "Error: [Errno 2] No such file"),
    ):
        r = CliRunner().invoke(command(exc), [])
        assert r.exit_code == 1 and r.output.startswith(shown), r.output
    # an engine argument the extension refuses is an EngineError (one line), and still a ValueError
    with pytest.raises(ArgumentError, match="method must be") as info:
        predicted_psf_seconds(method="nope", pixel_um=1.0, size=64, pupil_samples=64)
    assert isinstance(info.value, EngineError) and isinstance(info.value, ValueError)
    # a bug is not dressed as a user error: it propagates with its type
    for bug in (ValueError("math domain error"), RuntimeError("shape mismatch"), KeyError("k")):
        r = CliRunner().invoke(command(bug), [])
        assert r.exit_code == 1 and r.exception is bug and "Error:" not in r.output, r.output
