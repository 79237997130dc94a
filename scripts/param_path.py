"""A command-line parameter's path through the package, read from the source: the functions and files its value
passes through from where it is born to its last read, and how often that path climbs the layers of
`[tool.importlinter]`.

    python scripts/param_path.py train train.bonus_weight
    python scripts/param_path.py pretrain            # every argument of `digail pretrain`, summed

The value is born twice: where the command line is parsed (the function that calls `tyro.cli` and hands the
arguments to the command's function), and, for a field of a nested config that starts from a preset
(`--train.*`, `--vae.*`), where the preset is read (`preset.get_preset`); from there it travels up through the
functions that return it to the command's `defaults(argv)`, and on to the parse. From the command's function the
path follows the value forward in source order: a call that passes it (or an object holding it: the arguments, a
config taken from them, `dataclasses.replace` of one, an object that keeps it in `self`) enters the callee, and
the path returns to the caller afterwards; only calls below which the value is read are taken (`.bonus_weight`;
for a whole nested config, any field of it; for a plain value, any use but passing it on), and the path ends at
the last read. Each step from a module to one of a higher layer is a climb (the preset's way up, a return to a
caller that goes on to pass the value elsewhere); a step within a layer or down is not.

Static and approximate: names are resolved through imports, `self` methods along the class's bases in the
package, return annotations and constructor calls; calls through a value of unknown type are not followed, and
both branches of an `if` are walked.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"


def layers() -> dict[str, int]:
    """Top-level module name (`cli`, `commands`, ...) -> its layer's index in `[tool.importlinter]` (0 highest)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    contract = next(c for c in config["tool"]["importlinter"]["contracts"] if c["type"] == "layers")
    return {name.strip(): i for i, layer in enumerate(contract["layers"]) for name in layer.split("|")}


@dataclasses.dataclass
class Function:
    module: str
    qualname: str
    node: ast.FunctionDef
    cls: str | None


class Index:
    """Every function, class and import of the package's source."""

    def __init__(self) -> None:
        self.functions: dict[str, Function] = {}
        self.classes: dict[str, tuple[str, ast.ClassDef]] = {}
        self.imports: dict[str, dict[str, str]] = {}
        for path in sorted((SRC / "digail").rglob("*.py")):
            module = ".".join(path.relative_to(SRC).with_suffix("").parts).removesuffix(".__init__")
            tree = ast.parse(path.read_text())
            names: dict[str, str] = {}
            for node in ast.walk(tree):  # lazy imports count: each name is looked up in its module
                if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                    for alias in node.names:
                        names[alias.asname or alias.name] = f"{node.module}.{alias.name}"
                elif isinstance(node, ast.Import):
                    for alias in node.names:
                        names[alias.asname or alias.name.split(".")[0]] = alias.name
            self.imports[module] = names
            for node in tree.body:
                if isinstance(node, ast.FunctionDef):
                    self.functions[f"{module}.{node.name}"] = Function(module, f"{module}.{node.name}", node, None)
                elif isinstance(node, ast.ClassDef):
                    self.classes[f"{module}.{node.name}"] = (module, node)
                    for item in node.body:
                        if isinstance(item, ast.FunctionDef):
                            q = f"{module}.{node.name}.{item.name}"
                            self.functions[q] = Function(module, q, item, f"{module}.{node.name}")

    def resolve(self, module: str, name: str) -> str:
        """A name used in `module` as the dotted name it stands for."""
        head, _, rest = name.partition(".")
        full = self.imports[module].get(head)
        if full is None:
            full = f"{module}.{head}"
        home, _, attr = full.rpartition(".")
        if (full not in self.classes and full not in self.functions and home != module
                and attr in self.imports.get(home, {})):
            full = self.resolve(home, attr)  # a name a package's `__init__` re-exports: its home module's
        return f"{full}.{rest}" if rest else full

    def method(self, cls: str, name: str) -> str | None:
        """`cls.name` looked up along the class's bases within the package."""
        seen = [cls]
        while seen:
            c = seen.pop(0)
            if f"{c}.{name}" in self.functions:
                return f"{c}.{name}"
            if c in self.classes:
                module, node = self.classes[c]
                seen += [self.resolve(module, ast.unparse(b)) for b in node.bases]
        return None


def _dotted(node: ast.expr) -> str | None:
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        return ".".join([node.id, *reversed(parts)])
    return None


Carriers = dict[str, tuple[str, ...]]
"""a name (`args`, `cfg`, `self.cfg`) -> the attribute path from it to the parameter (() for the value itself)"""


class Tracer:
    def __init__(self, index: Index, field: tuple[str, ...], whole: bool) -> None:
        self.index, self.field, self.whole = index, field, whole
        self.passed: set[int] = set()  # the argument nodes of the current statement that pass the value on
        self.active: set[tuple[str, tuple[tuple[str, tuple[str, ...]], ...]]] = set()
        self.stored: dict[str, Carriers] = {}  # class -> carriers it keeps in `self`

    def carried(self, expr: ast.expr, carriers: Carriers) -> tuple[str, ...] | None:
        """The remaining path to the parameter if `expr` holds it (a carrier, a prefix of its path, or
        `dataclasses.replace` of one), else None."""
        if isinstance(expr, ast.Call) and _dotted(expr.func) in ("replace", "dataclasses.replace") and expr.args:
            return self.carried(expr.args[0], carriers)
        name = _dotted(expr)
        if name is None:
            return None
        for carrier, rest in carriers.items():
            if name == carrier or name.startswith(carrier + "."):
                taken = tuple(name[len(carrier):].split(".")[1:]) if name != carrier else ()
                if rest[:len(taken)] == taken:
                    return rest[len(taken):]
        return None

    def reads(self, node: ast.AST, carriers: Carriers, passed: set[int]) -> bool:
        """Whether `node` reads the parameter: an attribute access that completes its path (for a whole nested
        config: any field of it), or a use of a name holding the value itself other than passing it to a function
        of the package (`passed`: the ids of those argument nodes), or keeping it in `self`."""
        if isinstance(node, ast.Assign):
            for t in node.targets:
                pairs = (list(zip(t.elts, node.value.elts, strict=False))
                         if isinstance(t, ast.Tuple) and isinstance(node.value, ast.Tuple) else [(t, node.value)])
                if any((_dotted(a) or "").startswith("self.") and self.carried(b, carriers) is not None
                       for a, b in pairs):
                    return True
        for sub in ast.walk(node):
            if id(sub) in passed:
                continue
            name = _dotted(sub) if isinstance(sub, ast.Name | ast.Attribute) else None
            if (name is not None and not self.whole and carriers.get(name) == () and _load(sub)
                    and not any(id(a) in passed for a in _ancestors_args(node, sub))):
                return True
            if isinstance(sub, ast.Attribute):
                name = _dotted(sub)
                if name is None:
                    continue
                for carrier, rest in carriers.items():
                    if not (name == carrier or name.startswith(carrier + ".")):
                        continue
                    taken = tuple(name[len(carrier):].split(".")[1:])
                    need = rest + (("*",) if self.whole else ())
                    if len(taken) >= len(need) and all(n in ("*", t) for n, t in zip(need, taken, strict=False)):
                        return True
        return False

    def callee(self, fn: Function, call: ast.Call, types: dict[str, str]) -> str | None:
        name = _dotted(call.func)
        if name is None:
            return None
        if name.startswith("self.") and fn.cls is not None and name.count(".") == 1:
            return self.index.method(fn.cls, name.split(".")[1])
        if name.startswith("super().") or (isinstance(call.func, ast.Attribute)
                                           and isinstance(call.func.value, ast.Call)
                                           and _dotted(call.func.value.func) == "super" and fn.cls):
            cls_module, cls_node = self.index.classes[fn.cls] if fn.cls else ("", None)
            for b in cls_node.bases if cls_node else []:
                found = self.index.method(self.index.resolve(cls_module, ast.unparse(b)), call.func.attr)  # type: ignore[attr-defined]
                if found:
                    return found
            return None
        head = name.split(".")[0]
        if head in types and "." in name:
            return self.index.method(types[head], name.split(".", 1)[1])
        full = self.index.resolve(fn.module, name)
        if full in self.index.functions:
            return full
        if full in self.index.classes:
            return self.index.method(full, "__init__") or self.index.method(full, "__post_init__")
        return None

    def returned_type(self, qual: str) -> str | None:
        f = self.index.functions.get(qual)
        if f is None or f.node.returns is None:
            return None
        full = self.index.resolve(f.module, ast.unparse(f.node.returns).strip("'\""))
        return full if full in self.index.classes else None

    def trace(self, qual: str, carriers: Carriers) -> list[tuple[str, bool]] | None:
        """The walk of the value from `qual` (entered with `carriers`): (function, whether it reads the value
        there) for every function entered and every return to a caller, in source order; None when the value is
        not read on any path from here."""
        key = (qual, tuple(sorted(carriers.items())))
        if key in self.active:
            return None  # recursion
        self.active.add(key)
        fn = self.index.functions[qual]
        carriers = dict(carriers)
        if fn.cls is not None:
            for cls, kept in self.stored.items():
                if self.index.method(fn.cls, "__init__") and cls in self._bases(fn.cls):
                    carriers.update(kept)
        types: dict[str, str] = {}
        walk: list[tuple[str, bool]] = [(qual, False)]
        read = False
        for stmt in _statements(fn.node.body):
            for sub in self.step(fn, stmt, carriers, types):
                walk += [*sub, (qual, False)]
                read = True
            if self.reads(stmt, carriers, self.passed):
                walk.append((qual, True))
                read = True
        self.active.discard(key)
        return walk if read else None

    def _bases(self, cls: str) -> list[str]:
        out, todo = [], [cls]
        while todo:
            c = todo.pop(0)
            out.append(c)
            if c in self.index.classes:
                module, node = self.index.classes[c]
                todo += [self.index.resolve(module, ast.unparse(b)) for b in node.bases]
        return out

    def step(self, fn: Function, stmt: ast.stmt, carriers: Carriers,
             types: dict[str, str]) -> list[list[tuple[str, bool]]]:
        """Follow one statement's calls that pass the value on (the walks below each that reaches a read), then
        its assignments (new names, or `self` attributes, that hold the value)."""
        found: list[list[tuple[str, bool]]] = []
        self.passed = set()
        calls = [n for n in ast.walk(stmt) if isinstance(n, ast.Call)]
        for call in sorted(calls, key=lambda c: (c.lineno, c.col_offset)):
            target = self.callee(fn, call, types)
            if target is None:
                continue
            callee = self.index.functions[target]
            params = [a.arg for a in [*callee.node.args.posonlyargs, *callee.node.args.args]]
            offset = 1 if params and params[0] == "self" else 0
            kwonly = [a.arg for a in callee.node.args.kwonlyargs]
            bound: Carriers = {}
            for i, arg in enumerate(call.args):
                rest = self.carried(arg, carriers)
                if rest is not None and i + offset < len(params):
                    bound[params[i + offset]] = rest
            for kw in call.keywords:
                rest = self.carried(kw.value, carriers) if kw.arg else None
                if rest is not None and (kw.arg in params or kw.arg in kwonly):
                    bound[str(kw.arg)] = rest
            self.passed |= {id(a) for a in [*call.args, *(k.value for k in call.keywords)]
                            if self.carried(a, carriers) is not None}
            holder = callee.cls is not None and any(c in self.stored for c in self._bases(callee.cls))
            if bound or holder:
                got = self.trace(target, bound)
                if got is not None:
                    found.append(got)
        if isinstance(stmt, ast.Assign | ast.AnnAssign):
            targets = stmt.targets if isinstance(stmt, ast.Assign) else [stmt.target]
            value = stmt.value
            pairs: list[tuple[ast.expr, ast.expr]] = []
            for t in targets if value is not None else []:
                if isinstance(t, ast.Tuple) and isinstance(value, ast.Tuple) and len(t.elts) == len(value.elts):
                    pairs += list(zip(t.elts, value.elts, strict=True))  # a, b = x, y
                elif value is not None:
                    pairs.append((t, value))
            for t, v in pairs:
                rest = self.carried(v, carriers)
                name = _dotted(t)
                if name and rest is not None:
                    carriers[name] = rest
                    if name.startswith("self.") and fn.cls:
                        self.stored.setdefault(fn.cls, {})[name] = rest
            if value is not None and isinstance(value, ast.Call):
                target = self.callee(fn, value, types)
                typ = self.returned_type(target) if target else None
                full = self.index.resolve(fn.module, _dotted(value.func) or "")
                typ = typ or (full if full in self.index.classes else None)
                for t in targets:
                    if isinstance(t, ast.Name) and typ:
                        types[t.id] = typ
        return found


def _load(node: ast.AST) -> bool:
    return isinstance(getattr(node, "ctx", None), ast.Load)


def _ancestors_args(root: ast.AST, target: ast.AST) -> list[ast.AST]:
    """The nodes between `root` and `target` (to tell a name inside a passed argument from a read)."""
    path: list[ast.AST] = []

    def visit(node: ast.AST) -> bool:
        if node is target:
            return True
        for child in ast.iter_child_nodes(node):
            if visit(child):
                path.append(node)
                return True
        return False

    visit(root)
    return path


def _statements(body: list[ast.stmt]) -> list[ast.stmt]:
    """Statements in source order, the bodies of compound statements flattened (both branches of an `if`)."""
    out: list[ast.stmt] = []
    for stmt in body:
        if isinstance(stmt, ast.If | ast.For | ast.While | ast.With | ast.Try):
            out.append(_header(stmt))
            for part in ("body", "orelse", "finalbody"):
                out += _statements(getattr(stmt, part, []) or [])
            for handler in getattr(stmt, "handlers", []):
                out += _statements(handler.body)
        else:
            out.append(stmt)
    return out


def _header(stmt: ast.stmt) -> ast.stmt:
    """The part of a compound statement evaluated before its body (test, iterable, context managers)."""
    if isinstance(stmt, ast.If | ast.While):
        return ast.Expr(stmt.test, lineno=stmt.lineno, col_offset=stmt.col_offset)
    if isinstance(stmt, ast.For):
        return ast.Assign([stmt.target], stmt.iter, lineno=stmt.lineno, col_offset=stmt.col_offset)
    if isinstance(stmt, ast.With):
        return ast.Expr(ast.Tuple([i.context_expr for i in stmt.items], ast.Load()), lineno=stmt.lineno,
                        col_offset=stmt.col_offset)
    return ast.Pass(lineno=stmt.lineno, col_offset=stmt.col_offset)


def preset_chain(index: Index, qual: str, seen: frozenset[str] = frozenset()) -> list[str]:
    """The functions the preset returns through, from where it is read up to `qual`: in `qual`, the call whose
    result is (or becomes) the returned preset, followed down to `preset.get_preset`."""
    if qual.endswith("preset.get_preset"):
        return [qual]
    fn = index.functions[qual]
    for node in ast.walk(fn.node):
        if isinstance(node, ast.Call):
            name = _dotted(node.func)
            full = index.resolve(fn.module, name) if name else ""
            if full in index.functions and full not in seen and _returns_preset(index, full, seen | {qual}):
                return [*preset_chain(index, full, seen | {qual}), qual]
    return [qual]


def _returns_preset(index: Index, qual: str, seen: frozenset[str]) -> bool:
    return preset_chain(index, qual, seen)[0].endswith("preset.get_preset")


def parse_site(index: Index) -> str:
    """The function that parses the command line (calls `tyro.cli`) and hands the arguments to the command."""
    for qual, fn in index.functions.items():
        for node in ast.walk(fn.node):
            if isinstance(node, ast.Call) and index.resolve(fn.module, _dotted(node.func) or "") == "tyro.cli":
                return qual
    raise SystemExit("no call of tyro.cli found")


def path_of(index: Index, command: str, field: tuple[str, ...]) -> list[str]:
    """The functions (dotted names) on the parameter's path, in order, starting where it is born."""
    module = f"digail.commands.{command}_" if command == "import" else f"digail.commands.{command}"
    handler = f"{module}.{command}_command"
    args_cls = next(c for c in index.classes if c.startswith(module + ".") and c.endswith("Args"))
    whole = False
    _, node = index.classes[args_cls]
    nested = {stmt.target.id for stmt in node.body if isinstance(stmt, ast.AnnAssign)  # type: ignore[union-attr]
              and isinstance(stmt.value, ast.Call) and "default_factory" in ast.unparse(stmt.value)}
    if len(field) == 1 and field[0] in nested:
        whole = True
    start: list[str] = []
    defaults = f"{module}.defaults"
    if field[0] in nested and defaults in index.functions:
        start = [*preset_chain(index, defaults)]
    start.append(parse_site(index))
    tracer = Tracer(index, field, whole)
    walk = tracer.trace(handler, {"args": field}) or [(handler, False)]
    last = max(i for i, (_, is_read) in enumerate(walk) if is_read) if any(r for _, r in walk) else 0
    steps = start + [q for q, _ in walk[:last + 1]]
    return [q for i, q in enumerate(steps) if i == 0 or q != steps[i - 1]]


def summary(path: list[str], rank: dict[str, int]) -> tuple[list[str], int]:
    """The files on the path (each once, in order) and the number of climbs (a step to a higher layer)."""
    def layer(q: str) -> int:
        top = q.split(".")[1]
        return rank.get(top, len(rank))

    files = list(dict.fromkeys(_file(q) for q in path))
    climbs = sum(1 for a, b in zip(path, path[1:], strict=False) if layer(b) < layer(a))
    return files, climbs


def _file(qual: str) -> str:
    parts = qual.split(".")
    for i in range(len(parts), 0, -1):
        base = SRC.joinpath(*parts[:i])
        if base.with_suffix(".py").is_file():
            return str(base.with_suffix(".py").relative_to(SRC))
        if (base / "__init__.py").is_file():
            return str((base / "__init__.py").relative_to(SRC))
    return qual


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("command", help="a subcommand, e.g. train")
    parser.add_argument("field", nargs="?", help="a dotted field of its arguments (e.g. train.bonus_weight); "
                        "default: every argument, summed")
    args = parser.parse_args()
    index, rank = Index(), layers()
    if args.field:
        fields = [tuple(args.field.replace("-", "_").split("."))]
    else:
        module = f"digail.commands.{args.command}"
        cls = next(c for c in index.classes if c.startswith(module + ".") and c.endswith("Args"))
        fields = [(s.target.id,) for s in index.classes[cls][1].body
                  if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)]
    all_files: list[str] = []
    total = 0
    for field in fields:
        path = path_of(index, args.command, field)
        files, climbs = summary(path, rank)
        all_files += files
        total += climbs
        print(f"--{'.'.join(field).replace('_', '-')}: {len(files)} files, {climbs} climbs")
        print("    " + " -> ".join(q.removeprefix("digail.") for q in path))
    if len(fields) > 1:
        print(f"all {len(fields)} arguments: {len(set(all_files))} files, {total} climbs")
    sys.exit(0)


if __name__ == "__main__":
    main()
