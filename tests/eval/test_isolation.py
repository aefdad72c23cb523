"""The product never imports evaluation: mogo_export and mogo_runtime work without mogo_eval.

Two checks, because each misses what the other sees: importing every product module in a fresh interpreter
(catches imports at module level, however spelled), and reading every product source file's import statements
(catches imports inside functions, which importing the module does not run).
"""
import ast
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

PRODUCT = ("mogo_export", "mogo_runtime")
EVAL = "mogo_eval"

# Imports every module of the product packages, then reports what of mogo_eval got loaded.
IMPORT_ALL = """
import importlib, json, pkgutil, sys
imported, failed = [], {}
for name in %r:
    pkg = importlib.import_module(name)
    imported.append(name)
    for m in pkgutil.walk_packages(pkg.__path__, name + "."):
        if m.name.rsplit(".", 1)[-1] == "__main__":
            continue
        try:
            importlib.import_module(m.name)
            imported.append(m.name)
        except ImportError as e:       # e.g. an optional dependency missing: reported, never hidden
            failed[m.name] = repr(e)
print(json.dumps({"imported": imported, "failed": failed,
                  "eval_loaded": sorted(k for k in sys.modules if k == %r or k.startswith(%r + "."))}))
""" % (PRODUCT, EVAL, EVAL)


def _package_dir(name: str) -> Path:
    spec = importlib.util.find_spec(name)
    assert spec is not None and spec.submodule_search_locations, f"{name} is not an importable package"
    return Path(next(iter(spec.submodule_search_locations)))


def test_importing_every_product_module_loads_no_evaluation_module():
    out = subprocess.run([sys.executable, "-c", IMPORT_ALL], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout.strip().splitlines()[-1])
    # A module that does not import at all is the product's tests' failure, not this one's (and the source
    # check below still reads it); what imported must be most of each package.
    for name in PRODUCT:
        assert sum(m.split(".")[0] == name for m in report["imported"]) >= 5, report
    assert report["eval_loaded"] == [], (f"the product imported evaluation: {report['eval_loaded']} "
                                         f"(modules that failed to import: {report['failed']})")


def _eval_imports(path: Path) -> list[str]:
    """Import statements of one source file that name mogo_eval (absolute ones; a relative import cannot
    reach a sibling top-level package)."""
    hits = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) in (
                "import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant):
            names = [str(node.args[0].value)]
        hits += [f"{path}:{node.lineno}: {n}" for n in names if n == EVAL or n.startswith(EVAL + ".")]
    return hits


def test_no_product_source_names_evaluation_in_an_import():
    files = [f for name in PRODUCT for f in sorted(_package_dir(name).rglob("*.py"))]
    assert len(files) > 10, files
    hits = [h for f in files for h in _eval_imports(f)]
    assert hits == [], "the product imports evaluation:\n" + "\n".join(hits)


def test_the_source_check_sees_an_import_inside_a_function(tmp_path):
    """The check can fail: a lazy import, the kind importing the module would not run."""
    f = tmp_path / "lazy.py"
    f.write_text("def report():\n    from mogo_eval.quality import quality_report\n    return quality_report\n")
    assert _eval_imports(f) == [f"{f}:2: mogo_eval.quality"]
    f.write_text("import importlib\nq = importlib.import_module('mogo_eval.protocol')\n")
    assert _eval_imports(f) == [f"{f}:2: mogo_eval.protocol"]
