"""Dependencies point one way (HELPERS.md, DESIGN.md): controllers, models, estimators and the
execution level never import the simulator, the I/O layer or the experiments; the simulator
never imports the experiments or the I/O layer; the controller registry imports none of them.

Every ``import`` statement is read from the source (the AST, so imports inside functions
count too), not from ``sys.modules``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "mpcasv"

#: package (or module) -> packages it may not import
FORBIDDEN = {
    "controllers": ("mpcasv.sim", "mpcasv.io", "mpcasv.experiments", "mpcasv.cli"),
    "hybrid": ("mpcasv.sim", "mpcasv.io", "mpcasv.experiments", "mpcasv.cli"),
    "mpc": ("mpcasv.sim", "mpcasv.io", "mpcasv.experiments", "mpcasv.cli"),
    "control": ("mpcasv.sim", "mpcasv.io", "mpcasv.experiments", "mpcasv.cli"),
    "estimation": ("mpcasv.sim", "mpcasv.io", "mpcasv.experiments", "mpcasv.cli"),
    "models": ("mpcasv.sim", "mpcasv.io", "mpcasv.experiments", "mpcasv.cli"),
    "sim": ("mpcasv.io", "mpcasv.experiments", "mpcasv.cli"),
    "interface.py": ("mpcasv.",),
    "config.py": ("mpcasv.",),
    "errors.py": ("mpcasv.",),
}

#: application modules inside those packages: command-line entry points and benchmarks that
#: drive the simulator (they sit at the top, beside mpcasv.cli), with the reason
APPLICATIONS = {
    "mpcasv.hybrid.commands": "mpcasv paper-table: runs the simulator",
    "mpcasv.control.commands": "mpcasv tune / identify: command line",
    "mpcasv.control.identify_cli": "mpcasv identify: command line (its checks and exit codes)",
    "mpcasv.mpc.bench": "mpcasv bench mpc: records closed-loop runs",
    "mpcasv.sim.bench": "mpcasv bench sim",
    "mpcasv.sim.commands": "mpcasv simulate: computes the metrics it writes",
    "mpcasv.estimation.evaluate": "estimator comparison harness: runs the simulator",
}

#: known upward imports still to remove: (module, imported name) -> why it is still there
KNOWN: dict[tuple[str, str], str] = {}


def _module_name(path: Path) -> str:
    rel = path.relative_to(PKG.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in ``path``."""
    mod = _module_name(path)
    package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative import
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                name = ".".join([*base, node.module] if node.module else base)
            else:
                name = node.module or ""
            out += [(node.lineno, name)] + [(node.lineno, f"{name}.{a.name}") for a in node.names]
    return out


def _files(key: str) -> list[Path]:
    target = PKG / key
    return [target] if target.suffix == ".py" else sorted(target.rglob("*.py"))


def _violations(key: str) -> list[str]:
    bad = []
    for path in _files(key):
        mod = _module_name(path)
        if mod in APPLICATIONS:
            continue
        for line, name in _imports(path):
            for prefix in FORBIDDEN[key]:
                hit = name == prefix.rstrip(".") or name.startswith(prefix.rstrip(".") + ".")
                if prefix == "mpcasv.":
                    hit = name.startswith("mpcasv.")
                if hit and not any(mod == m and name.startswith(t) for m, t in KNOWN):
                    bad.append(f"{path.relative_to(PKG.parent)}:{line}: imports {name}")
    return sorted(set(bad))


@pytest.mark.parametrize("key", sorted(FORBIDDEN))
def test_no_upward_imports(key):
    assert _violations(key) == []


def test_the_check_sees_an_upward_import(tmp_path, monkeypatch):
    """The walker finds imports at module level, inside functions and relative ones."""
    pkg = tmp_path / "mpcasv" / "hybrid"
    pkg.mkdir(parents=True)
    (pkg / "x.py").write_text(
        "import mpcasv.sim.world\n"
        "def f():\n    from mpcasv.experiments import metrics\n"
        "from ..io import lsf\n"
        "from mpcasv.models import params\n"
    )  # fmt: skip
    monkeypatch.setattr(__import__(__name__), "PKG", tmp_path / "mpcasv")
    found = _violations("hybrid")
    assert [v.split(": imports ")[1] for v in found] == [
        "mpcasv.sim.world", "mpcasv.experiments", "mpcasv.experiments.metrics", "mpcasv.io",
        "mpcasv.io.lsf",
    ]  # fmt: skip


def test_known_exceptions_are_still_needed():
    """An entry of KNOWN that no longer matches an import must be deleted (it would hide a
    future upward import)."""
    for mod, target in KNOWN:
        path = PKG.parent / (mod.replace(".", "/") + ".py")
        assert any(n.startswith(target) for _, n in _imports(path)), (mod, target)
