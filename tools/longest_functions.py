"""The longest and the widest functions of the package, from its source (nothing is imported).

    python tools/longest_functions.py                 # the 15 longest and the 15 widest
    python tools/longest_functions.py --top 40 --all  # private functions too
    python tools/longest_functions.py --check         # exit 1 if a public function is over the limits

*Length* counts code lines of the body: from the first statement after the docstring to the
function's end, without blank lines and comment lines. *Width* counts parameters (``self`` and ``cls`` left out,
``*args`` and ``**kwargs`` counted once each). A function is *public* when neither its name nor
that of a class or module around it (up to the package) starts with an underscore; methods of
public classes count, dunder methods (``__init__``) too.

``--check`` exits 1 and names every public function longer than ``--max-lines`` (80) or wider
than ``--max-params`` (10).
"""

from __future__ import annotations

import argparse
import ast
import io
import sys
import tokenize
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "vehicle_detection"


@dataclass(frozen=True)
class Function:
    where: str  # module.Class.function
    path: Path
    line: int
    lines: int
    params: int
    public: bool


def _comment_or_blank_lines(source: str) -> set[int]:
    """Line numbers (1-based) holding nothing but a comment or whitespace."""
    code: set[int] = set()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type not in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
                            tokenize.ENDMARKER):
            code.update(range(tok.start[0], tok.end[0] + 1))
    return set(range(1, source.count("\n") + 2)) - code


def _docstring_lines(node: ast.AST) -> set[int]:
    body = getattr(node, "body", [])
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
        return set(range(body[0].lineno, body[0].end_lineno + 1))
    return set()


def _n_params(fn: ast.FunctionDef | ast.AsyncFunctionDef, method: bool) -> int:
    a = fn.args
    names = [p.arg for p in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    if method and names and names[0] in ("self", "cls"):
        names = names[1:]
    return len(names) + (a.vararg is not None) + (a.kwarg is not None)


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def functions(package: Path = PACKAGE) -> list[Function]:
    """Every function and method of the package's modules (nested functions included)."""
    out: list[Function] = []
    for path in sorted(package.rglob("*.py")):
        source = path.read_text(encoding="utf-8")
        skip = _comment_or_blank_lines(source)
        parts = path.relative_to(package.parent).with_suffix("").parts
        module = ".".join(p for p in parts if p != "__init__")
        hidden = any(_private(p) for p in parts if p not in ("__init__", "__main__"))

        def visit(node: ast.AST, prefix: str, private: bool, in_class: bool) -> None:
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.ClassDef):
                    visit(child, f"{prefix}.{child.name}", private or _private(child.name), True)
                elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    body = child.body[1:] if _docstring_lines(child) else child.body
                    span = set(range(body[0].lineno, child.end_lineno + 1)) - skip if body else set()
                    name = f"{prefix}.{child.name}"
                    is_private = private or _private(child.name)
                    out.append(Function(name, path, child.lineno, len(span), _n_params(child, in_class), not is_private))
                    visit(child, name, True, False)  # nested functions are not public
                else:
                    visit(child, prefix, private, in_class)

        visit(ast.parse(source, str(path)), module, hidden, False)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--top", type=int, default=15, help="how many of each to print (default %(default)s)")
    p.add_argument("--all", action="store_true", help="private functions too (default: public only)")
    p.add_argument("--check", action="store_true", help="exit 1 if a public function is over the limits")
    p.add_argument("--max-lines", type=int, default=80)
    p.add_argument("--max-params", type=int, default=10)
    args = p.parse_args(argv)
    found = functions()
    shown = found if args.all else [f for f in found if f.public]

    def row(f: Function) -> str:
        return f"{f.lines:5d} lines {f.params:3d} params  {f.where}  ({f.path.relative_to(REPO)}:{f.line})"

    print(f"{len(found)} functions, {sum(f.public for f in found)} public; "
          f"{'all' if args.all else 'public'} ones, longest first:")
    for f in sorted(shown, key=lambda f: (-f.lines, f.where))[: args.top]:
        print(row(f))
    print("widest first:")
    for f in sorted(shown, key=lambda f: (-f.params, f.where))[: args.top]:
        print(row(f))
    if not args.check:
        return 0
    over = [f for f in found if f.public and (f.lines > args.max_lines or f.params > args.max_params)]
    for f in over:
        print(f"over the limits ({args.max_lines} lines, {args.max_params} params): {row(f)}", file=sys.stderr)
    return 1 if over else 0


if __name__ == "__main__":
    sys.exit(main())
