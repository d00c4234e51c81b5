#!/usr/bin/env python3
"""Finds import circles between the files of each crate of the workspace (`make lint`).

A file imports another when its code names something defined there: a `use` of
`crate::`, `super::` or `self::` paths, or such a path written inline. A name taken through
a re-export (`pub use`) counts as an import of the file that defines it, and a re-export
itself is no import: a crate's face hands names on without depending on them. Test modules
(`#[cfg(test)]`) and the crates' `tests/` folders are left out. Files that import each other
in a loop are printed with the names that tie them, and the exit status is 1.

Usage: tools/import_circles.py [WORKSPACE]   (default: the folder above this script's)
"""

import re
import sys
from pathlib import Path

COMMENT = re.compile(r"//[^\n]*|/\*.*?\*/", re.S)
STRING = re.compile(r'r(#*)".*?"\1|"(?:\\.|[^"\\])*"|\'(?:\\.|[^\'\\])\'', re.S)
USE = re.compile(r"\b(pub(?:\([^)]*\))?\s+)?use\s+([^;]+);")
INLINE = re.compile(r"\b(?:crate|super|self)(?:::\w+)+")
TEST_ITEM = re.compile(r"#\[cfg\(test\)\]\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+\w+\s*\{")


def module_path(src: Path, file: Path) -> tuple:
    """The module a file is (`()` for lib.rs or main.rs)."""
    parts = list(file.relative_to(src).with_suffix("").parts)
    if parts[-1] in ("mod", "lib", "main") and (parts[-1] == "mod" or len(parts) == 1):
        parts.pop()
    return tuple(parts)


def without_tests(text: str) -> str:
    """The text with each `#[cfg(test)] mod ... { ... }` cut out."""
    while match := TEST_ITEM.search(text):
        depth, i = 1, match.end()
        while depth and i < len(text):
            depth += {"{": 1, "}": -1}.get(text[i], 0)
            i += 1
        text = text[: match.start()] + text[i:]
    return text


def use_paths(tree: str, prefix=()) -> list:
    """Every path of a `use` tree (`a::{b, c::{d as e}}`), each a tuple of names."""
    tree = tree.strip()
    if not tree:
        return []
    depth = 0
    for i, c in enumerate(tree):
        depth += {"{": 1, "}": -1}.get(c, 0)
        if c == "{" and depth == 1:
            head = tuple(p for p in tree[:i].split("::") if p.strip())
            inner, paths, depth, start = tree[i + 1 : tree.rindex("}")], [], 0, 0
            for j, d in enumerate(inner + ","):
                depth += {"{": 1, "}": -1}.get(d, 0)
                if d == "," and depth == 0:
                    paths += use_paths(inner[start:j], prefix + tuple(h.strip() for h in head))
                    start = j + 1
            return paths
    path = tree.split(" as ")[0].strip()
    return [prefix + tuple(p.strip() for p in path.split("::"))]


def absolute(path: tuple, here: tuple, children: set):
    """`path` as seen from module `here`, from the crate root; None where it leaves the crate."""
    if path[0] == "crate":
        return path[1:]
    if path[0] in ("self", "super"):
        base = list(here)
        while path and path[0] in ("self", "super"):
            if path[0] == "super":
                base.pop()
            path = path[1:]
        return tuple(base) + path
    if path[0] in children:
        return here + path
    return None


class Crate:
    def __init__(self, src: Path):
        self.files = {}
        for file in sorted(src.rglob("*.rs")):
            text = without_tests(STRING.sub('""', COMMENT.sub("", file.read_text())))
            self.files[module_path(src, file)] = (file, text)
        self.exports = {m: {} for m in self.files}
        self.uses = {m: [] for m in self.files}
        for module, (_, text) in self.files.items():
            children = {m[-1] for m in self.files if m[:-1] == module and m != module}
            for public, tree in USE.findall(text):
                for path in use_paths(tree):
                    full = absolute(path, module, children)
                    if full is None:
                        continue
                    if public:
                        self.exports[module][path[-1]] = full
                    else:
                        self.uses[module].append(full)
            for path in INLINE.findall(USE.sub("", text)):
                full = absolute(tuple(path.split("::")), module, children)
                if full is not None:
                    self.uses[module].append(full)

    def defining(self, path: tuple, seen=()):
        """The file module that defines what `path` names, following re-exports."""
        for cut in range(len(path), -1, -1):
            module, rest = path[:cut], path[cut:]
            if module in self.files:
                target = self.exports[module].get(rest[0]) if rest else None
                if target is not None and target not in seen:
                    return self.defining(target + rest[1:], seen + (target,))
                return module, (rest[0] if rest else "*")
        return None

    def imports(self) -> dict:
        """{(from, to): names}: the files each file takes names from."""
        edges = {}
        for module, paths in self.uses.items():
            for path in paths:
                found = self.defining(path)
                if found and found[0] != module:
                    edges.setdefault((module, found[0]), set()).add(found[1])
        return edges


def circles(nodes, edges) -> list:
    """The strongly connected components of more than one node (Tarjan's algorithm)."""
    graph = {n: [b for (a, b) in edges if a == n] for n in nodes}
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(n):
        index[n] = low[n] = len(index)
        stack.append(n)
        on.add(n)
        for m in graph[n]:
            if m not in index:
                visit(m)
                low[n] = min(low[n], low[m])
            elif m in on:
                low[n] = min(low[n], index[m])
        if low[n] == index[n]:
            component = []
            while True:
                m = stack.pop()
                on.discard(m)
                component.append(m)
                if m == n:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for n in nodes:
        if n not in index:
            visit(n)
    return out


def main() -> int:
    root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent)
    found = 0
    for manifest in sorted(root.glob("*/Cargo.toml")) + [root / "Cargo.toml"]:
        src = manifest.parent / "src"
        if not src.is_dir() or "vendor" in manifest.parts:
            continue
        crate = Crate(src)
        edges = crate.imports()
        for circle in circles(list(crate.files), edges):
            found += 1
            name = lambda m: str(crate.files[m][0].relative_to(root))
            print(f"import circle: {', '.join(name(m) for m in circle)}")
            for (a, b), names in sorted(edges.items()):
                if a in circle and b in circle:
                    print(f"  {name(a)} -> {name(b)}: {', '.join(sorted(names))}")
    if found:
        print(f"{found} import circle(s): move what ties them to a file both can import")
        return 1
    print("no import circles")
    return 0


if __name__ == "__main__":
    sys.exit(main())
