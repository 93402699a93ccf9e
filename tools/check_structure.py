"""List what breaks pcreg's structure targets, read from the sources with ``ast``.

    python tools/check_structure.py [pcreg]      # one line per finding; exit status 1 when there is any

The targets: no file over 600 lines, no function over 80; no public function or constructor (a dataclass's
fields count as its constructor's parameters) over 12 parameters; no module-level mutable state (a
module-level dict, list or set that a function changes, a ``global`` statement, an ``lru_cache`` /
``cache``). Module-level state a module documents as one per process is listed too: a line to read,
not a verdict. Pairs of repeated code are the ``duplicates`` command's.
"""

from __future__ import annotations

import ast
from pathlib import Path

MAX_FILE_LINES = 600
MAX_FUNCTION_LINES = 80
MAX_PARAMETERS = 12
_MUTATORS = {"append", "extend", "insert", "update", "setdefault", "pop", "popitem", "clear", "add", "discard",
             "remove"}
_CONTAINERS = (ast.Dict, ast.List, ast.Set, ast.DictComp, ast.ListComp, ast.SetComp)


def _parameters(args: ast.arguments) -> int:
    n = len(args.posonlyargs) + len(args.args) + len(args.kwonlyargs) + (args.vararg is not None) + (args.kwarg is not None)
    return n - 1 if args.args and args.args[0].arg in ("self", "cls") else n


def _name(node: ast.expr) -> str:
    return ast.unparse(node.func if isinstance(node, ast.Call) else node).split(".")[-1]


def _definitions(path: Path, tree: ast.AST, prefix: str = "", public: bool = True):
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            name = prefix + node.name
            length = node.end_lineno - node.lineno + 1
            if length > MAX_FUNCTION_LINES:
                yield f"{path}:{node.lineno} {name}: {length} lines"
            shown = public and (not node.name.startswith("_") or node.name == "__init__")
            if shown and _parameters(node.args) > MAX_PARAMETERS:
                yield f"{path}:{node.lineno} {name}: {_parameters(node.args)} parameters"
            for deco in node.decorator_list:
                if _name(deco) in ("lru_cache", "cache"):
                    yield f"{path}:{node.lineno} {name}: @{ast.unparse(deco)}"
            yield from _definitions(path, node, name + ".", False)
        elif isinstance(node, ast.ClassDef):
            name = prefix + node.name
            shown = public and not node.name.startswith("_")
            if shown and any(_name(d) == "dataclass" for d in node.decorator_list):
                n = sum(isinstance(s, ast.AnnAssign) and "ClassVar" not in ast.unparse(s.annotation) for s in node.body)
                if n > MAX_PARAMETERS:
                    yield f"{path}:{node.lineno} {name}: a dataclass of {n} fields"
            yield from _definitions(path, node, name + ".", shown)


def _module_state(path: Path, tree: ast.Module):
    containers = {}
    for st in tree.body:
        value = st.value if isinstance(st, (ast.Assign, ast.AnnAssign)) else None
        targets = st.targets if isinstance(st, ast.Assign) else [st.target] if isinstance(st, ast.AnnAssign) else []
        if isinstance(value, _CONTAINERS) or (isinstance(value, ast.Call) and _name(value) in ("dict", "list", "set")):
            containers.update({t.id: st.lineno for t in targets if isinstance(t, ast.Name)})
    changed = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Global):
            for name in node.names:
                yield f"{path}:{node.lineno} global {name}"
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in _MUTATORS
              and isinstance(node.func.value, ast.Name) and node.func.value.id in containers):
            changed.setdefault(node.func.value.id, node.lineno)
        elif isinstance(node, (ast.Assign, ast.AugAssign, ast.Delete)):
            for t in node.targets if isinstance(node, (ast.Assign, ast.Delete)) else [node.target]:
                if isinstance(t, ast.Subscript) and isinstance(t.value, ast.Name) and t.value.id in containers:
                    changed.setdefault(t.value.id, node.lineno)
    for name, line in changed.items():
        yield f"{path}:{line} {name} (module level, line {containers[name]}) is changed"


def findings(root: Path) -> list[str]:
    """Every finding under ``root``, file by file."""
    out = []
    for path in sorted(root.rglob("*.py")):
        text = path.read_text()
        lines = text.count("\n") + (not text.endswith("\n"))
        if lines > MAX_FILE_LINES:
            out.append(f"{path}: {lines} lines")
        tree = ast.parse(text)
        out += [*_definitions(path, tree), *_module_state(path, tree)]
    return out


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("package", nargs="?", default="pcreg", help="the package's folder (default: pcreg)")
    package = Path(ap.parse_args(argv).package)
    if not package.is_dir() or not any(package.rglob("*.py")):
        ap.error(f"{package}: no folder of Python files")  # a mistyped path checked nothing, and passed
    found = findings(package)
    print("\n".join(found) if found else "no findings")
    return 1 if found else 0


if __name__ == "__main__":
    raise SystemExit(main())
