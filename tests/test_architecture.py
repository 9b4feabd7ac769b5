"""The layering of docs/architecture.md, enforced on the source (an AST walk, so imports
inside functions count): a module imports only from its own subpackage, the foundations and
the layers below; nothing imports the CLI; the Rust extension is imported only by the
engine's door, optix_e2e.engine."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "optix_e2e"

#: Each subpackage or top-level module and its layer (docs/architecture.md); a module may import
#: what sits on a lower layer, never a sibling of its own layer nor anything above.
LAYER = {
    "_engine": 0,
    "errors": 0,
    "device": 1,
    "precision": 1,
    "engine": 2,
    "io": 2,
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


def test_nothing_imports_the_cli():
    bad = [f"{m}:{line}" for m, t, line in _imports() if _top(t) == "cli" and _top(m) not in ("cli", "__main__")]
    assert not bad, bad


def test_the_extension_is_imported_only_through_the_engine_door():
    importers = {m for m, t, _ in _imports() if "_engine" in t.split(".")}
    assert importers == {"engine"}, f"import the engine through optix_e2e.engine, not _engine: {sorted(importers)}"


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
