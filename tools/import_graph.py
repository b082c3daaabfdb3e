#!/usr/bin/env python3
"""In-crate import graph of relief's two crates, and its circles.

    python3 tools/import_graph.py [--crate core|app|both] [--level module|file]
                                  [--order m1,m2,...] [--tests] [--no-follow] [--facade-edges]
                                  [--edges] [--json] [--check]

Standard library only; reads the sources, never builds them.

Crates and roots (module trees follow the `mod` declarations from each root, `foo.rs` + `foo/`
and `foo/mod.rs`; files no declaration reaches are reported as orphans):
  core   src/core/lib.rs   (`crate::`; `relief_core::` inside the core is read as `crate::`)
  app    src/lib.rs        (the `relief` library; `pub use relief_core::*` makes `crate::format`
                           etc. core paths, counted as references *to the core*, not edges)
         src/main.rs       (the `relief` binary, module `cli`; `relief::render::..` is an edge to
                           the library's module, `relief::format::..` a reference to the core)

A reference is a leaf of a `use` tree (nested groups, `self`, `as`, globs, `pub use`) or a
qualified path in code (`crate::a::B`, `super::x::y`, `self::..`, a child module's name, or a
name a `use` bound to a module, e.g. `use crate::format; .. format::terrain::TerrainFile`).
Paths starting with a name bound to a non-module item (`Foo::new`) are not counted again: the
`use` line is the reference. Comments, doc comments, string/char literals are stripped by a
small lexer. Items under `#[cfg(test)]` (test modules, `mod tests;` files, single test-only
fns or fields) are skipped and counted separately; `--tests` includes them.

A path is resolved to the module that *defines* the item: through `use` bindings (private ones
too, since `super::Name` can name them) and `pub use` / glob re-exports (`--no-follow` stops at
the module the path names). A `pub use` line is itself a reference from the re-exporting file.

Granularity: `--level module` groups files by top-level module of their crate (`error`,
`format`, `refine`, ...; the crate root is `<root>`, the binary's modules are `bin:cli`,
`bin:<main>`); `--level file` is one node per file. At file level a module's own file naming
its submodules (a mod.rs re-exporting or dispatching to its children) is the facade direction
and is left out (counted); `--facade-edges` keeps it, which makes every mod.rs whose children
use `super::` items a circle of its own.

Report: strongly connected components with more than one node (Tarjan), and for each a set of
edges that closes its cycles: the edges going upward against an order of the component's
nodes (`--order` lowest layer first, nodes not listed placed by a greedy feedback-arc heuristic
weighted by reference counts), pruned to an inclusion-minimal set (an upward edge that closes
no cycle once the others are cut is put back). Each closing edge lists its files, lines and
referenced items. With `--order`, every edge of the whole graph that points upward against
it is listed too (the layering rule: only downward arrows). `--check` prints the report and
exits 1 if there is a circle (or, with `--order`, an upward edge), else prints
"no import circles" and exits 0. `--edges` lists every edge with its reference count.
"""

import argparse
import bisect
import json
import os
import re
import signal
import sys
from collections import defaultdict

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

KEYWORDS_ITEM = {"fn", "struct", "enum", "union", "trait", "type", "const", "static"}

# ---------------------------------------------------------------------------------------------
# Lexer: identifiers, `::`, punctuation; comments, strings, chars, lifetimes and numbers dropped.


TOKEN = re.compile(r"""
    (?P<lc>//[^\n]*)
  | (?P<bc>/\*(?:.*?\*/)?)
  | (?P<raw>[bc]?r(?P<hashes>\#*)".*?"(?P=hashes))
  | (?P<str>[bc]?"(?:[^"\\]|\\.)*")
  | (?P<chr>b?'(?:\\'|\\[^']+|[^\\'])')
  | (?P<life>'[A-Za-z_]\w*)
  | (?P<id>r\#[A-Za-z_]\w*|[A-Za-z_]\w*)
  | (?P<num>\d\w*)
  | (?P<dc>\$crate)
  | (?P<p>::|[{}()\[\];,\#!*.])
""", re.X | re.S)


def lex(src):
    """Tokens (kind, text, offset), kind 'id' or 'p'; comments, string and char literals,
    lifetimes, numbers and punctuation the parser does not need are dropped. Block comments
    may nest."""
    if "/*" not in src:  # fast path: no block comment to nest
        out = []
        for m in TOKEN.finditer(src):
            k = m.lastgroup
            if k == "id":
                t = m.group()
                out.append(("id", t[2:] if t[:2] == "r#" else t, m.start()))
            elif k == "p":
                out.append(("p", m.group(), m.start()))
            elif k == "dc":
                out.append(("id", "crate", m.start()))
        return out
    toks = []
    append = toks.append
    pos, n = 0, len(src)
    search = TOKEN.search
    while True:
        m = search(src, pos)
        if m is None:
            break
        kind = m.lastgroup
        pos = m.end()
        if kind == "id":
            t = m.group()
            append(("id", t[2:] if t[0] == "r" and t[1:2] == "#" else t, m.start()))
        elif kind == "p":
            append(("p", m.group(), m.start()))
        elif kind == "dc":
            append(("id", "crate", m.start()))
        elif kind == "bc":
            depth, j = 1, m.start() + 2
            while depth:
                o, c = src.find("/*", j), src.find("*/", j)
                if c < 0:
                    j = n
                    break
                if 0 <= o < c:
                    depth, j = depth + 1, o + 2
                else:
                    depth, j = depth - 1, c + 2
            pos = j
    return toks


# ---------------------------------------------------------------------------------------------
# Per-file parse: inline modules, cfg(test) items, use trees, qualified paths, item definitions.


class Module:
    def __init__(self, crate, path, file, test=False):
        self.crate, self.path, self.file, self.test = crate, tuple(path), file, test
        self.children = {}  # name -> Module
        self.defs = set()  # item names defined here
        self.bindings = {}  # name -> (abs path tuple | ('<ext>', crate, ...), is_pub)
        self.globs = []  # abs path tuples
        self.file_mods = []  # (name, is_test, line)  `mod name;`


def is_test_cfg(attr):
    """attr: token texts inside #[...]; true for cfg(test) and cfg(all(.., test, ..))."""
    if len(attr) < 4 or attr[0] != "cfg" or attr[1] != "(":
        return False
    if attr[2] == "test" and attr[3] == ")":
        return True
    if attr[2] == "all":
        return "test" in attr[3:] and "not" not in attr[3:]
    return False


def matching(toks, i):
    """index of the token closing the bracket at toks[i]."""
    pairs = {"{": "}", "(": ")", "[": "]"}
    open_, close, depth = toks[i][1], pairs[toks[i][1]], 0
    for j in range(i, len(toks)):
        t = toks[j][1]
        if toks[j][0] != "p":
            continue
        if t == open_:
            depth += 1
        elif t == close:
            depth -= 1
            if depth == 0:
                return j
    return len(toks) - 1


def skip_item(toks, i):
    """toks[i] starts an item / field / statement: index just after it."""
    j, first_kw = i, None
    while j < len(toks):
        kind, t, _ = toks[j]
        if kind == "id" and first_kw is None and t in (
                "fn", "struct", "enum", "union", "trait", "impl", "mod", "macro_rules",
                "const", "static", "type", "use", "let", "extern"):
            first_kw = t
        if kind == "p":
            if t in "([":
                j = matching(toks, j) + 1
                continue
            if t == "{":
                j = matching(toks, j) + 1
                if first_kw not in ("const", "static", "type", "use", "let", None):
                    return j
                continue
            if t in ";,":
                return j + 1
            if t == "}":
                return j
        j += 1
    return j


def parse_use_tree(toks, i, prefix, out):
    """Parse a use tree at toks[i]; appends (segments, alias, line) to out; returns end index."""
    segs = list(prefix)
    line = toks[i][2] if i < len(toks) else 0
    while i < len(toks):
        kind, t, line = toks[i]
        if kind == "id":
            if t == "as":
                alias = toks[i + 1][1]
                out.append((segs, alias, line))
                return i + 2
            segs.append(t)
            i += 1
        elif t == "::":
            i += 1
        elif t == "*":
            out.append((segs, "*", line))
            return i + 1
        elif t == "{":
            end = matching(toks, i)
            i += 1
            while i < end:
                if toks[i][1] == ",":
                    i += 1
                    continue
                i = parse_use_tree(toks, i, segs, out)
            return end + 1
        else:
            break
    if segs and segs[-1] == "self":
        segs = segs[:-1]
        out.append((segs, segs[-1] if segs else "self", line))
    elif segs:
        out.append((segs, segs[-1], line))
    return i


class FileInfo:
    def __init__(self, crate, rel, modpath):
        self.crate, self.rel, self.modpath = crate, rel, tuple(modpath)
        self.uses = []  # (module path tuple, segs, alias, line, is_pub, is_test)
        self.paths = []  # (module path tuple, segs, line, is_test)
        self.test_items = 0
        self.test_lines = 0


def parse_file(info, src, modules, crate, make_module):
    toks = lex(src)  # (kind, text, offset): offsets become line numbers where recorded
    nl = [m.start() for m in re.finditer("\n", src)]

    def L(offset):
        return bisect.bisect_right(nl, offset) + 1
    # scope stack: (module, brace depth at which its body lives)
    stack = [(modules[info.modpath], 0)]
    depth = 0
    pending_test = False
    test_until = -1  # index until which tokens are inside a cfg(test) item
    test_depth_stack = []
    i = 0
    n = len(toks)
    in_test = lambda: i < test_until
    while i < n:
        kind, t, line = toks[i]
        mod = stack[-1][0]
        # attributes
        if kind == "p" and t == "#":
            j = i + 1
            inner = j < n and toks[j][1] == "!"
            if inner:
                j += 1
            if j < n and toks[j][1] == "[":
                end = matching(toks, j)
                attr = [x[1] for x in toks[j + 1:end]]
                if is_test_cfg(attr):
                    if inner and depth == stack[-1][1]:
                        mod.test = True
                    else:
                        pending_test = True
                i = end + 1
                continue
        if pending_test and i < test_until:
            pending_test = False  # already inside a test-only item
        if pending_test:
            pending_test = False
            # skip visibility to see what the item is
            j = i
            while j < n and toks[j][1] in ("pub",):
                j += 1
                if j < n and toks[j][1] == "(":
                    j = matching(toks, j) + 1
            end = skip_item(toks, i)
            info.test_items += 1
            info.test_lines += L(toks[end - 1][2]) - L(line) + 1 if end - 1 < n else 0
            if j + 2 < n and toks[j][1] == "mod" and toks[j + 2][1] == ";":
                mod.file_mods.append((toks[j + 1][1], True, L(line)))
                i = end
                continue
            test_until = end
            # fall through: parse the item's contents, marked as test
        tst = i < test_until
        if kind == "p":
            if t == "{":
                depth += 1
            elif t == "}":
                depth -= 1
                if len(stack) > 1 and depth < stack[-1][1]:
                    stack.pop()
            i += 1
            continue
        # identifiers
        if t == "mod" and i + 2 < n and toks[i + 1][0] == "id":
            name = toks[i + 1][1]
            if toks[i + 2][1] == ";":
                mod.file_mods.append((name, False, L(line)))
                i += 3
                continue
            if toks[i + 2][1] == "{":
                child = make_module(crate, mod.path + (name,), info.rel, mod.test or tst)
                mod.children[name] = child
                mod.defs.add(name)
                depth += 1
                stack.append((child, depth))
                i += 3
                continue
        if t == "use" and (i == 0 or toks[i - 1][1] != "::"):
            is_pub = False
            k = i - 1
            if k >= 0 and toks[k][1] == ")":
                while k >= 0 and toks[k][1] != "(":
                    k -= 1
                k -= 1
            if k >= 0 and toks[k][1] == "pub":
                is_pub = True
            out = []
            j = i + 1
            if j < n and toks[j][1] == "::":
                j += 1
            j = parse_use_tree(toks, j, [], out)
            for segs, alias, ln in out:
                info.uses.append((mod.path, segs, alias, L(ln), is_pub, tst or mod.test))
            while j < n and toks[j][1] != ";":
                j += 1
            i = j + 1
            continue
        if depth == stack[-1][1] and t in KEYWORDS_ITEM and i + 1 < n and toks[i + 1][0] == "id":
            nm = toks[i + 1][1]
            if nm not in ("fn", "unsafe", "extern", "async"):
                mod.defs.add(nm)
        if depth == stack[-1][1] and t == "macro_rules" and i + 2 < n:
            mod.defs.add(toks[i + 2][1])
        # qualified path in code
        if (i == 0 or toks[i - 1][1] != "::") and i + 1 < n and toks[i + 1][1] == "::":
            segs = [t]
            j = i + 1
            while j + 1 < n and toks[j][1] == "::" and toks[j + 1][0] == "id":
                segs.append(toks[j + 1][1])
                j += 2
            info.paths.append((mod.path, segs, L(line), tst or mod.test))
            i = j
            continue
        i += 1


# ---------------------------------------------------------------------------------------------
# Crates


class Crate:
    def __init__(self, name, root_file, label, aliases, externs):
        self.name, self.root_file, self.label = name, root_file, label
        self.aliases = aliases  # names that mean this crate's root (`crate`, `relief_core` in core)
        self.externs = externs  # extern crate name -> Crate
        self.modules = {}  # path tuple -> Module
        self.files = {}  # rel -> FileInfo
        self.orphans = []


def mod_files(parent_file, name):
    d = os.path.dirname(parent_file)
    base = os.path.basename(parent_file)
    if base not in ("lib.rs", "main.rs", "mod.rs"):
        d = os.path.join(d, base[:-3])
    for cand in (os.path.join(d, name + ".rs"), os.path.join(d, name, "mod.rs")):
        if os.path.isfile(os.path.join(REPO, cand)):
            return cand
    return None


def load_crate(crate, opts):
    def make_module(cr, path, file, test):
        m = Module(cr.name, path, file, test)
        cr.modules[tuple(path)] = m
        return m

    todo = [(crate.root_file, (), False)]
    while todo:
        rel, path, test = todo.pop()
        info = FileInfo(crate.name, rel, path)
        crate.files[rel] = info
        m = make_module(crate, path, rel, test)
        if path:
            crate.modules[path[:-1]].children[path[-1]] = m
            crate.modules[path[:-1]].defs.add(path[-1])
        with open(os.path.join(REPO, rel), encoding="utf-8") as f:
            src = f.read()
        parse_file(info, src, crate.modules, crate, make_module)
        info.test = m.test
        for name, is_test, _ in m.file_mods:
            child = mod_files(rel, name)
            if child:
                todo.append((child, path + (name,), test or is_test))
    return crate


def resolve(crate, mod_path, segs, crates, bound_only_modules=False):
    """Resolve a path written in module `mod_path` of `crate`.

    Returns (crate_name, module path tuple, item or None, via) or None (not in-crate / unknown)."""
    mods = crate.modules
    first = segs[0]
    rest = list(segs[1:])
    start = None
    if first in crate.aliases:
        start = ()
    elif first == "self":
        start = mod_path
    elif first == "super":
        p = list(mod_path)
        p = p[:-1]
        while rest and rest[0] == "super":
            p = p[:-1]
            rest.pop(0)
        start = tuple(p)
    elif first in crate.externs:
        ext = crate.externs[first]
        return resolve_abs(ext, (), rest, crates, [])
    else:
        # a child module of the current module, or a name bound by `use` in this module or an
        # enclosing inline module of the same file (uses inside fn bodies are module-scoped here)
        p = tuple(mod_path)
        m = mods.get(p)
        if m is None:
            return None
        if first in m.children:
            start, rest = p, [first] + rest
        elif first in m.bindings:
            target = m.bindings[first][0]
            r = resolve_binding(crate, target, rest, crates, [])
            if r is None:
                return None
            if bound_only_modules and r[2] is not None:
                return None  # `Foo::new`: the `use` of Foo is the reference
            return r
        else:
            return None
    return resolve_abs(crate, start, rest, crates, [])


def resolve_binding(crate, target, rest, crates, seen):
    if target and target[0] == "<ext>":
        ext = crates[target[1]]
        return resolve_abs(ext, (), list(target[2:]) + rest, crates, seen)
    return resolve_abs(crate, (), list(target) + rest, crates, seen)


def resolve_abs(crate, start, rest, crates, seen, follow=True):
    mods = crate.modules
    node = tuple(start)
    if node not in mods:
        return None
    rest = list(rest)
    via = []
    while rest:
        m = mods[node]
        name = rest[0]
        if name in m.children:
            node = node + (name,)
            rest.pop(0)
            continue
        if not FOLLOW or name in m.defs:
            break
        key = (crate.name, node, name)
        if key in seen:
            break
        if name in m.bindings:
            target = m.bindings[name][0]
            r = resolve_binding(crate, target, rest[1:], crates, seen + [key])
            if r is not None:
                return (r[0], r[1], r[2], [(crate.name, node)] + r[3])
            break
        hit = None
        for g in m.globs:
            if g and g[0] == "<ext>":
                ext = crates[g[1]]
                r = resolve_abs(ext, tuple(g[2:]), rest, crates, seen + [key])
                if r is not None and (r[1] != tuple(g[2:]) or r[2] is None or
                                      r[2] in ext.modules[r[1]].defs):
                    hit = r
                    break
                continue
            gm = mods.get(tuple(g))
            if gm and (name in gm.defs or name in gm.bindings or name in gm.children):
                hit = resolve_abs(crate, tuple(g), rest, crates, seen + [key])
                break
        if hit is not None:
            return (hit[0], hit[1], hit[2], [(crate.name, node)] + hit[3])
        break
    item = rest[0] if rest else None
    return (crate.name, node, item, via)


FOLLOW = True


def build(opts):
    core = Crate("core", "src/core/lib.rs", "core", {"crate", "relief_core"}, {})
    lib = Crate("app", "src/lib.rs", "app", {"crate", "relief"}, {"relief_core": core})
    bin_ = Crate("bin", "src/main.rs", "bin", {"crate"}, {"relief": lib, "relief_core": core})
    crates = {"core": core, "app": lib, "bin": bin_}
    for c in crates.values():
        load_crate(c, opts)
    # bindings: first pass records raw paths; resolve relative starts to absolute module paths
    for c in crates.values():
        for info in c.files.values():
            for mpath, segs, alias, line, is_pub, tst in info.uses:
                if not segs:
                    continue
                absp = absolutize(c, mpath, segs, crates)
                if absp is None:
                    continue
                m = c.modules[mpath]
                if alias == "*":
                    m.globs.append(absp)
                elif alias != "_":
                    m.bindings.setdefault(alias, (absp, is_pub))
    # orphans: .rs files under each crate's directory no `mod` reached
    reached = set()
    for c in crates.values():
        reached.update(c.files)
    for c, top in ((core, "src/core"), (lib, "src")):
        for dp, dns, fns in os.walk(os.path.join(REPO, top)):
            if c is lib and os.path.relpath(dp, REPO).startswith("src/core"):
                continue
            for fn in fns:
                rel = os.path.relpath(os.path.join(dp, fn), REPO)
                if fn.endswith(".rs") and rel not in reached:
                    c.orphans.append(rel)
    return crates


def absolutize(c, mpath, segs, crates):
    first, rest = segs[0], list(segs[1:])
    if first in c.aliases:
        return tuple(rest)
    if first == "self":
        return tuple(mpath) + tuple(rest)
    if first == "super":
        p = list(mpath)[:-1]
        while rest and rest[0] == "super":
            p, rest = p[:-1], rest[1:]
        return tuple(p) + tuple(rest)
    if first in c.externs:
        return ("<ext>", c.externs[first].name) + tuple(rest)
    m = c.modules.get(tuple(mpath))
    if m is not None and first in m.children:
        return tuple(mpath) + tuple(segs)
    return None  # std, external crates


# ---------------------------------------------------------------------------------------------
# Graph


def top_node(crate_name, modpath, level, files_of):
    if level == "file":
        return files_of
    if crate_name == "bin":
        return "bin:" + (modpath[0] if modpath else "<main>")
    return (modpath[0] if modpath else "<root>")


def collect(crates, which, level, include_tests, facade_edges=False):
    """Returns nodes, edges {(u,v): [ref]}, external refs count, test-skipped count."""
    wanted = {"core": ["core"], "app": ["app", "bin"], "both": ["core", "app", "bin"]}[which]
    prefix = which == "both"
    nodes = set()
    edges = defaultdict(list)
    ext_refs = defaultdict(int)
    skipped_tests = 0
    facades = [0]

    def name(crate_name, modpath, rel):
        nm = top_node(crate_name, modpath, level, rel)
        if prefix and level == "module":
            nm = {"core": "core:", "app": "app:", "bin": ""}[crate_name] + nm
        return nm

    def file_of(crate_name, modpath):
        c = crates[crate_name]
        p = tuple(modpath)
        while p not in c.modules:
            p = p[:-1]
        return c.modules[p].file

    for cn in wanted:
        c = crates[cn]
        for rel, info in c.files.items():
            nodes.add(name(cn, info.modpath, rel))
            refs = []
            for mpath, segs, alias, line, is_pub, tst in info.uses:
                if segs:
                    refs.append((mpath, segs, line, tst, "pub use" if is_pub else "use", False))
            for mpath, segs, line, tst in info.paths:
                refs.append((mpath, segs, line, tst, "path", True))
            for mpath, segs, line, tst, how, bound_only in refs:
                r = resolve(c, mpath, segs, crates, bound_only_modules=bound_only)
                if r is None:
                    continue
                tcn, tpath, item, via = r
                if tst and not include_tests:
                    skipped_tests += 1
                    continue
                if tcn not in wanted:
                    ext_refs[(cn, tcn)] += 1
                    continue
                src_node = name(cn, mpath, rel)
                tfile = file_of(tcn, tpath)
                dst = name(tcn, tpath, tfile)
                if src_node == dst:
                    continue
                if (level == "file" and not facade_edges and tcn == cn
                        and tpath[:len(mpath)] == tuple(mpath) and len(tpath) > len(info.modpath)
                        and tpath[:len(info.modpath)] == info.modpath):
                    # a module's own file naming its descendants (mod.rs re-exporting or
                    # dispatching to its children): the facade direction, not an upward arrow
                    facades[0] += 1
                    continue
                written = "::".join(segs)
                shown = "::".join(tpath) + ("::" + item if item else "")
                edges[(src_node, dst)].append({
                    "file": rel, "line": line, "written": written, "resolved": shown,
                    "target_file": tfile, "kind": how, "test": tst,
                })
                nodes.add(dst)
    return nodes, edges, ext_refs, skipped_tests, facades[0]


def tarjan(nodes, adj):
    index, low, on, st, out = {}, {}, set(), [], []
    counter = [0]
    sys.setrecursionlimit(10000)

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        st.append(v)
        on.add(v)
        for w in sorted(adj.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = st.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            out.append(sorted(comp))

    for v in sorted(nodes):
        if v not in index:
            strong(v)
    return out


def weight(refs):
    # distinct (file, line, resolved) references
    return len({(r["file"], r["line"], r["resolved"]) for r in refs})


def greedy_order(comp, edges):
    """Eades-Lin-Smyth: an order (lowest first) with few/light upward edges."""
    comp = set(comp)
    w = {(u, v): weight(r) for (u, v), r in edges.items() if u in comp and v in comp}
    remaining = set(comp)
    low_side, high_side = [], []  # low_side: sinks first (things depended on)

    def outw(v):
        return sum(x for (a, b), x in w.items() if a == v and b in remaining)

    def inw(v):
        return sum(x for (a, b), x in w.items() if b == v and a in remaining)

    while remaining:
        changed = True
        while changed:
            changed = False
            for v in sorted(remaining):
                if outw(v) == 0:  # depends on nothing left: lowest
                    low_side.append(v)
                    remaining.discard(v)
                    changed = True
            for v in sorted(remaining):
                if inw(v) == 0:  # nothing left depends on it: highest
                    high_side.insert(0, v)
                    remaining.discard(v)
                    changed = True
        if remaining:
            # the node whose dependants outweigh its dependencies goes low
            v = max(sorted(remaining), key=lambda x: inw(x) - outw(x))
            low_side.append(v)
            remaining.discard(v)
    return low_side + high_side


def reaches(adj, src, dst, cut):
    seen, todo = {src}, [src]
    while todo:
        v = todo.pop()
        if v == dst:
            return True
        for x in adj.get(v, ()):
            if (v, x) not in cut and x not in seen:
                seen.add(x)
                todo.append(x)
    return False


def closing_edges(comp, edges, order_hint):
    comp_set = set(comp)
    listed = [x for x in order_hint if x in comp_set]
    rest = [x for x in greedy_order([x for x in comp if x not in listed], edges)]
    order = listed + rest if listed else greedy_order(comp, edges)
    pos = {v: i for i, v in enumerate(order)}
    adj = defaultdict(set)
    for (u, v) in edges:
        if u in comp_set and v in comp_set:
            adj[u].add(v)
    # upward: u depends on v placed above u
    up = [(u, v) for (u, v) in edges if u in comp_set and v in comp_set and pos[v] > pos[u]]
    cut = set(up)
    # make it inclusion-minimal: put back (heaviest first) every edge that closes no cycle
    for e in sorted(up, key=lambda e: -weight(edges[e])):
        cut.discard(e)
        if reaches(adj, e[1], e[0], cut):
            cut.add(e)
    return order, sorted(cut, key=lambda e: (weight(edges[e]), e))


def group_items(refs):
    by_file = defaultdict(lambda: defaultdict(set))
    for r in refs:
        by_file[r["file"]][r["resolved"]].add(r["line"])
    return by_file


def main(argv=None):
    global FOLLOW
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--crate", choices=("core", "app", "both"), default="both")
    ap.add_argument("--level", choices=("module", "file"), default="module")
    ap.add_argument("--order", default="", help="proposed layer order, lowest first, comma-separated")
    ap.add_argument("--tests", action="store_true", help="include #[cfg(test)] items")
    ap.add_argument("--no-follow", action="store_true", help="do not resolve through re-exports")
    ap.add_argument("--facade-edges", action="store_true",
                    help="file level: keep references from a module's file to its own submodules")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--check", action="store_true")
    ap.add_argument("--edges", action="store_true", help="also list every edge of the graph")
    a = ap.parse_args(argv)
    FOLLOW = not a.no_follow
    crates = build(a)
    nodes, edges, ext_refs, skipped, facades = collect(crates, a.crate, a.level, a.tests,
                                                       a.facade_edges)
    adj = defaultdict(set)
    for (u, v) in edges:
        adj[u].add(v)
    sccs = [c for c in tarjan(nodes, adj) if len(c) > 1]
    hint = [x.strip() for x in a.order.split(",") if x.strip()]
    result = {"crate": a.crate, "level": a.level, "nodes": len(nodes), "edges": len(edges),
              "references": sum(weight(r) for r in edges.values()),
              "test_references_skipped": skipped,
              "facade_references_skipped": facades,
              "cross_crate_references": {f"{s}->{t}": k for (s, t), k in sorted(ext_refs.items())},
              "orphan_files": sorted(o for c in crates.values() for o in c.orphans),
              "test_files": sorted(i.rel for c in crates.values() for i in c.files.values() if i.test),
              "circles": []}
    for comp in sccs:
        order, cut = closing_edges(comp, edges, hint)
        internal = [(u, v) for (u, v) in edges if u in comp and v in comp]
        result["circles"].append({
            "nodes": comp, "internal_edges": len(internal), "order": order,
            "closing_edges": [{"from": u, "to": v, "references": weight(edges[(u, v)]),
                               "refs": edges[(u, v)]} for (u, v) in cut],
        })
    if hint:
        pos = {v: i for i, v in enumerate(hint)}
        result["unlisted_nodes"] = sorted(v for v in nodes if v not in pos)
        result["against_order"] = [
            {"from": u, "to": v, "references": weight(r), "refs": r}
            for (u, v), r in sorted(edges.items(), key=lambda kv: (weight(kv[1]), kv[0]))
            if u in pos and v in pos and pos[v] > pos[u]]
    if a.edges:
        result["all_edges"] = [{"from": u, "to": v, "references": weight(r)}
                               for (u, v), r in sorted(edges.items())]
    if a.json:
        print(json.dumps(result, indent=1))
        return 1 if (a.check and (sccs or (hint and result["against_order"]))) else 0
    upward = bool(hint) and bool(result["against_order"])
    if a.check and not sccs and not upward:
        print("no import circles" + (" and no edge against --order" if hint else ""))
        return 0
    print(f"{a.crate} crate(s), {a.level} level: {len(nodes)} nodes, {len(edges)} edges, "
          f"{result['references']} references ({skipped} in #[cfg(test)] code skipped"
          + (f", {facades} from a module's file into its own submodules skipped" if facades else "")
          + ")")
    for k, v in result["cross_crate_references"].items():
        print(f"  references across crates {k}: {v}")
    if result["orphan_files"]:
        print("  files no `mod` reaches: " + ", ".join(result["orphan_files"]))
    if not sccs:
        print("no import circles")
    for ci, circ in enumerate(result["circles"], 1):
        print(f"\ncircle {ci}: {len(circ['nodes'])} nodes, {circ['internal_edges']} edges among them")
        print("  nodes: " + ", ".join(circ["nodes"]))
        print("  order (lowest first): " + " < ".join(circ["order"]))
        print(f"  closed by {len(circ['closing_edges'])} upward edge(s):")
        for e in circ["closing_edges"]:
            print(f"    {e['from']} -> {e['to']}  ({e['references']} reference(s))")
            for f, items in sorted(group_items(e["refs"]).items()):
                for it, lines in sorted(items.items()):
                    print(f"      {f}:{','.join(map(str, sorted(lines)))}  {it}")
    if hint:
        ups = result["against_order"]
        print(f"\n--order: {len(ups)} edge(s) point upward against it"
              + (f"; not placed: {', '.join(result['unlisted_nodes'])}" if result["unlisted_nodes"] else ""))
        for e in ups:
            print(f"    {e['from']} -> {e['to']}  ({e['references']} reference(s))")
            for f, items in sorted(group_items(e["refs"]).items()):
                for it, lines in sorted(items.items()):
                    print(f"      {f}:{','.join(map(str, sorted(lines)))}  {it}")
    if a.edges:
        print("\nedges:")
        for e in result["all_edges"]:
            print(f"  {e['from']} -> {e['to']}  {e['references']}")
    return 1 if (a.check and (sccs or upward)) else 0


if __name__ == "__main__":
    if hasattr(signal, "SIGPIPE"):
        signal.signal(signal.SIGPIPE, signal.SIG_DFL)  # `| head` ends quietly
    sys.exit(main())
